//! The JSON problem format of `snakectl solve`.
