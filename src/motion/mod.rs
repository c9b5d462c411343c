//! Tip motion per tick (pure).
