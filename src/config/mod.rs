//! The one config file: raw serde tables, then validated types.
