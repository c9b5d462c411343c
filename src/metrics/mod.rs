//! The paper's five motion metrics between an old and a new configuration.
