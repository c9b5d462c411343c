//! The teleop terminal UI's parts that are not the terminal: what keys and a joystick ask for
//! ([`input`], pure: events and time in, actions out), the joystick device ([`joystick`]), and
//! the drawing of the arm and its state ([`ui`], onto any ratatui backend).

pub mod input;
pub mod joystick;
pub mod ui;
