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

/// Seconds after the start as a duration; refuses what a duration cannot hold.
fn secs(index: usize, s: f64) -> Result<Duration, SimBusError> {
    Duration::try_from_secs_f64(s.max(0.0)).map_err(|_| SimBusError::Unsupported {
        index,
        reason: "a fault time is beyond what the simulator's clock can represent",
    })
}

/// `fault` limited to `at_s..until_s`; left standing when the window is the whole run.
fn windowed(
    index: usize,
    fault: SimFault,
    at_s: f64,
    until_s: Option<f64>,
) -> Result<SimFault, SimBusError> {
    if at_s <= 0.0 && until_s.is_none() {
        return Ok(fault);
    }
    let end = until_s.map(|u| secs(index, u)).transpose()?;
    Ok(fault.during(secs(index, at_s)?, end))
}

fn fault(index: usize, f: &Fault) -> Result<SimFault, SimBusError> {
    match *f {
        Fault::Drop {
            fraction,
            id,
            at_s,
            until_s,
        } => windowed(index, SimFault::DropReplies { id, fraction }, at_s, until_s),
        Fault::Corrupt {
            fraction,
            id,
            at_s,
            until_s,
        } => windowed(
            index,
            SimFault::CorruptReplies { id, fraction },
            at_s,
            until_s,
        ),
        Fault::Latency {
            extra_us,
            id,
            at_s,
            until_s,
        } => windowed(
            index,
            SimFault::ExtraLatency {
                id,
                latency: Duration::from_micros(u64::from(extra_us)),
            },
            at_s,
            until_s,
        ),
        // Silent from `at_s`; a window closing at `until_s` brings the servo back.
        Fault::Silent { id, at_s, until_s } => windowed(
            index,
            SimFault::Silent {
                id,
                at: secs(index, at_s)?,
            },
            0.0,
            until_s,
        ),
        Fault::HardwareError { id, at_s, error } => Ok(SimFault::HardwareError {
            id,
            at: secs(index, at_s)?,
            kind: hardware(error),
        }),
    }
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
    fn fault_windows_map_onto_the_simulator() {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml"))
            .unwrap()
            + "\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.1\nat_s = 2.0\n"
            + "\n[[sim.fault]]\nkind = \"corrupt\"\nfraction = 0.2\nid = 3\nuntil_s = 1.5\n"
            + "\n[[sim.fault]]\nkind = \"latency\"\nextra_us = 700\nat_s = 1.0\nuntil_s = 4.0\n"
            + "\n[[sim.fault]]\nkind = \"silent\"\nid = 5\nat_s = 2.5\nuntil_s = 3.0\n"
            + "\n[[sim.fault]]\nkind = \"silent\"\nid = 6\nat_s = 1.0\n"
            + "\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.3\n";
        let config = Config::from_str(&text, "sim.toml").unwrap();
        let sim = sim_config(&config).unwrap();
        let s = Duration::from_secs_f64;
        let base = sim.faults.len() - 6;
        assert_eq!(
            sim.faults[base..],
            [
                SimFault::DropReplies {
                    id: None,
                    fraction: 0.1
                }
                .during(s(2.0), None),
                SimFault::CorruptReplies {
                    id: Some(3),
                    fraction: 0.2
                }
                .during(Duration::ZERO, Some(s(1.5))),
                SimFault::ExtraLatency {
                    id: None,
                    latency: Duration::from_micros(700)
                }
                .during(s(1.0), Some(s(4.0))),
                SimFault::Silent { id: 5, at: s(2.5) }.during(Duration::ZERO, Some(s(3.0))),
                SimFault::Silent { id: 6, at: s(1.0) },
                SimFault::DropReplies {
                    id: None,
                    fraction: 0.3
                },
            ]
        );
        // And the simulator accepts them.
        let clock = std::sync::Arc::new(snakectl_sim::ManualClock::new());
        snakectl_sim::Simulator::new(sim, clock).unwrap();
    }
}
