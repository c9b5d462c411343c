//! One control tick (pure).
