//! The tractrix step.
