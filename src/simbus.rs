//! The simulated servo chain of a config file: the plain data `snakectl-sim` takes (servo ids,
//! models, position limits, the home pose as the power-on position, faults), built from the
//! validated config.

use std::time::Duration;

use snakectl_sim::{Fault as SimFault, HardwareErrorKind, Model, ServoSpec, SimConfig};

use crate::config::{raw, Config, Fault, ServoModel};
use crate::servo::units::Calibration;

/// Why a config cannot run on the simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SimBusError {
    /// A joint without a servo id or model.
    #[error("joint[{joint}]: the simulator needs an id and a model for every joint")]
    MissingServo {
        /// 1-based joint index.
        joint: usize,
    },
    /// A fault the simulator cannot reproduce as written.
    #[error("sim.fault[{index}]: {reason}")]
    Unsupported {
        /// 1-based fault index.
        index: usize,
        /// What is not simulated.
        reason: &'static str,
    },
}

fn model(m: ServoModel) -> Model {
    match m {
        ServoModel::Xl430W250 => Model::Xl430W250,
        ServoModel::Xm430W350 => Model::Xm430W350,
        ServoModel::Xl330M288 => Model::Xl330M288,
    }
}

fn hardware(e: raw::HardwareError) -> HardwareErrorKind {
    match e {
        raw::HardwareError::Overload => HardwareErrorKind::Overload,
        raw::HardwareError::Overheating => HardwareErrorKind::Overheating,
        raw::HardwareError::InputVoltage => HardwareErrorKind::InputVoltage,
        raw::HardwareError::ElectricalShock => HardwareErrorKind::ElectricalShock,
        raw::HardwareError::Encoder => HardwareErrorKind::Encoder,
    }
}

/// Refuses a time window the simulator cannot apply to a standing fault.
fn whole_run(index: usize, at_s: f64, until_s: Option<f64>) -> Result<(), SimBusError> {
    if at_s != 0.0 || until_s.is_some() {
        return Err(SimBusError::Unsupported {
            index,
            reason: "drop, corrupt and latency faults apply for the whole run: remove at_s/until_s",
        });
    }
    Ok(())
}

fn fault(index: usize, f: &Fault) -> Result<SimFault, SimBusError> {
    Ok(match *f {
        Fault::Drop {
            fraction,
            id,
            at_s,
            until_s,
        } => {
            whole_run(index, at_s, until_s)?;
            SimFault::DropReplies { id, fraction }
        }
        Fault::Corrupt {
            fraction,
            id,
            at_s,
            until_s,
        } => {
            whole_run(index, at_s, until_s)?;
            SimFault::CorruptReplies { id, fraction }
        }
        Fault::Latency {
            extra_us,
            id,
            at_s,
            until_s,
        } => {
            whole_run(index, at_s, until_s)?;
            SimFault::ExtraLatency {
                id,
                latency: Duration::from_micros(u64::from(extra_us)),
            }
        }
        Fault::Silent { id, at_s, until_s } => {
            if until_s.is_some() {
                return Err(SimBusError::Unsupported {
                    index,
                    reason: "a silent servo stays silent: remove until_s",
                });
            }
            SimFault::Silent {
                id,
                at: Duration::from_secs_f64(at_s.max(0.0)),
            }
        }
        Fault::HardwareError { id, at_s, error } => SimFault::HardwareError {
            id,
            at: Duration::from_secs_f64(at_s.max(0.0)),
            kind: hardware(error),
        },
    })
}

/// The simulator's configuration for the arm of `config`: one servo per joint with the joint's
/// limits as position limits, powered on at the home pose; the bus settings of `[bus]` and the
/// faults and timing of `[sim]`.
pub fn sim_config(config: &Config) -> Result<SimConfig, SimBusError> {
    let mut servos = Vec::with_capacity(config.joints().len());
    for (i, (joint, home)) in config.joints().iter().zip(config.home()).enumerate() {
        let (Some(id), Some(m)) = (joint.id, joint.model) else {
            return Err(SimBusError::MissingServo { joint: i + 1 });
        };
        let cal = Calibration {
            offset_ticks: joint.offset_ticks,
            reverse: joint.reverse,
        };
        let (lo, hi) = cal.tick_range(joint.limit.lo, joint.limit.hi);
        let mut spec = ServoSpec::new(id, model(m));
        spec.min_position_ticks = Some(lo.clamp(0.0, 4095.0) as u32);
        spec.max_position_ticks = Some(hi.clamp(0.0, 4095.0) as u32);
        spec.initial_position_ticks = Some(cal.ticks(*home).round() as i32);
        servos.push(spec);
    }
    let mut out = SimConfig {
        servos,
        ..SimConfig::default()
    };
    if let Some(bus) = config.bus() {
        out.baud = bus.baud;
        out.return_delay_us = bus.return_delay_us;
    }
    if let Some(sim) = config.sim() {
        out.wire_timing = sim.wire_timing;
        out.seed = sim.seed;
        out.faults = sim
            .faults
            .iter()
            .enumerate()
            .map(|(i, f)| fault(i + 1, f))
            .collect::<Result<_, _>>()?;
    }
    Ok(out)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_sim_config_maps_onto_twelve_servos() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
        let config = Config::load(path).unwrap();
        let sim = sim_config(&config).unwrap();
        assert_eq!(sim.servos.len(), 12);
        assert_eq!(sim.baud, 1_000_000);
        assert_eq!(sim.return_delay_us, 0);
        for (i, s) in sim.servos.iter().enumerate() {
            assert_eq!(usize::from(s.id), i + 1);
            assert_eq!(s.model, Model::Xl430W250);
            let (lo, hi) = (s.min_position_ticks.unwrap(), s.max_position_ticks.unwrap());
            let home = s.initial_position_ticks.unwrap();
            assert!(lo < hi && (lo as i32) <= home && home <= hi as i32);
        }
    }

    #[test]
    fn windows_the_simulator_cannot_apply_are_refused() {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml"))
            .unwrap()
            + "\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.1\nat_s = 2.0\n";
        let config = Config::from_str(&text, "sim.toml").unwrap();
        let err = sim_config(&config).unwrap_err();
        assert!(err.to_string().starts_with("sim.fault["), "{err}");
    }
}
