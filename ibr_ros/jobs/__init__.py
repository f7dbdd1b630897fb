"""Jobs behind the ibr subcommands: whole-file conversions built from core, msg_utils and bag."""
