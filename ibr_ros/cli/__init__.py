# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The ``ibr`` command line tool: one module per subcommand group, each with ``register()``."""
