//! The teleop screen: the arm drawn from `describe` and telemetry, its state beside it, a
//! key-help line; onto any ratatui backend.
