//! This tick's measurements in SI units, from the servos' raw readings: joint angles and
//! speeds every read, load, input voltage and temperature on health reads. Pure.

use crate::protocol::LoadUnit;
use crate::servo::arm::Arm;
use crate::servo::units::{self, Calibration, CurrentUnit};
use crate::servo::ServoState;

/// What the loop last measured of every joint.
#[derive(Debug, Clone)]
pub struct Measured {
    /// Joint angles, rad.
    pub theta: Vec<f64>,
    /// Joint speeds, rad/s.
    pub omega: Vec<f64>,
    /// Present Temperature, °C.
    pub temperature_c: Vec<f64>,
    /// Present Input Voltage, V.
    pub voltage_v: Vec<f64>,
    /// Present Load (percent) or Current (A), per `load_unit`.
    pub load: Vec<f64>,
    /// The unit of each joint's `load`.
    pub load_unit: Vec<LoadUnit>,
    /// The tick of the last health read.
    pub health_tick: u64,
    /// Which joints' temperature and voltage the last health read brought (the others keep
    /// their earlier values and are not judged on them).
    pub fresh: Vec<bool>,
    joints: Vec<(Calibration, CurrentUnit)>,
}

impl Measured {
    /// `arm`'s joints, at `pose`, at rest, nothing else known yet.
    pub fn new(arm: &Arm, pose: &[f64]) -> Self {
        let n = arm.joints().len();
        let joints: Vec<(Calibration, CurrentUnit)> = arm
            .joints()
            .iter()
            .map(|j| (j.calibration, j.model.current_unit()))
            .collect();
        Self {
            theta: pose.to_vec(),
            omega: vec![0.0; n],
            temperature_c: vec![0.0; n],
            voltage_v: vec![0.0; n],
            load: vec![0.0; n],
            load_unit: joints
                .iter()
                .map(|(_, u)| match u {
                    CurrentUnit::LoadPermille => LoadUnit::Percent,
                    CurrentUnit::MilliAmps(_) => LoadUnit::Amps,
                })
                .collect(),
            health_tick: 0,
            fresh: vec![false; n],
            joints,
        }
    }

    /// A health read begins: nothing is fresh yet.
    pub fn begin_health(&mut self) {
        self.fresh.iter_mut().for_each(|f| *f = false);
    }

    /// Joint `i`'s reading, in its joint's frame.
    pub fn record(&mut self, i: usize, s: &ServoState) {
        let Some(&(cal, unit)) = self.joints.get(i) else {
            return;
        };
        self.theta[i] = cal.radians(f64::from(s.position_ticks));
        if let Some(v) = s.velocity {
            self.omega[i] = units::velocity_rad_s(v) * cal.sign();
        }
        if let Some(c) = s.current {
            self.load[i] = cal.sign() * unit.value(c);
        }
        if let (Some(dv), Some(t)) = (s.voltage_dv, s.temperature_c) {
            self.voltage_v[i] = units::volts(dv);
            self.temperature_c[i] = f64::from(t);
            self.fresh[i] = true;
        }
    }

    /// Joint `i`'s position alone (a pose read), in its joint's frame.
    pub fn record_position(&mut self, i: usize, position_ticks: i32) {
        if let Some(&(cal, _)) = self.joints.get(i) {
            self.theta[i] = cal.radians(f64::from(position_ticks));
        }
    }
}
