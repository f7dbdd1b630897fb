# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Jobs behind the ibr subcommands: whole-file conversions built from core, msg_utils and bag."""
