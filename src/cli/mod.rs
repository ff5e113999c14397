//! The `imulab` subcommands, one module each.
