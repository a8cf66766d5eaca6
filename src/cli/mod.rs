//! Command-line interface (clap definitions).
