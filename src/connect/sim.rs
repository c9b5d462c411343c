//! The simulated servo chain of a config file: the plain data `snakectl-sim` takes (servo ids,
//! models, position limits, the home pose as the power-on position, faults), built from the
//! validated config.

use snakectl_sim::{Fault as SimFault, HardwareErrorKind, Model, ServoSpec, SimConfig};

use crate::config::{Config, Fault, FaultKind, HardwareError};

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
    /// The file has no `[bus]`, so no bus settings for the servos.
    #[error("the simulator needs a [bus] table (kind = \"sim\")")]
    NoBus,
    /// A model the simulator has no control table for.
    #[error("joint[{joint}].model: the simulator does not model the {model}")]
    NotSimulated {
        /// 1-based joint index.
        joint: usize,
        /// The model's name.
        model: &'static str,
    },
}

fn hardware(e: HardwareError) -> HardwareErrorKind {
    match e {
        HardwareError::Overload => HardwareErrorKind::Overload,
        HardwareError::Overheating => HardwareErrorKind::Overheating,
        HardwareError::InputVoltage => HardwareErrorKind::InputVoltage,
        HardwareError::ElectricalShock => HardwareErrorKind::ElectricalShock,
        HardwareError::Encoder => HardwareErrorKind::Encoder,
    }
}

/// The simulator's fault for a validated one: kept standing when its window is the whole run.
fn fault(f: &Fault) -> SimFault {
    let sim = match f.kind {
        FaultKind::Drop(fraction) => SimFault::DropReplies { id: f.id, fraction },
        FaultKind::Corrupt(fraction) => SimFault::CorruptReplies { id: f.id, fraction },
        FaultKind::Latency(latency) => SimFault::ExtraLatency { id: f.id, latency },
        // Silent from `from`; a window closing at `until` brings the servo back.
        FaultKind::Silent => {
            let silent = SimFault::Silent {
                id: f.id.unwrap_or_default(),
                at: f.from,
            };
            return match f.until {
                Some(_) => silent.during(std::time::Duration::ZERO, f.until),
                None => silent,
            };
        }
        // Blocked from `from`; a window closing at `until` lets the shaft go.
        FaultKind::Blocked => {
            let blocked = SimFault::Blocked {
                id: f.id.unwrap_or_default(),
                at: f.from,
            };
            return match f.until {
                Some(_) => blocked.during(std::time::Duration::ZERO, f.until),
                None => blocked,
            };
        }
        // The adapter unplugged: always windowed, even from 0 to the end of the run.
        FaultKind::Disconnect => return SimFault::Disconnect.during(f.from, f.until),
        FaultKind::HardwareError(e) => {
            return SimFault::HardwareError {
                id: f.id.unwrap_or_default(),
                at: f.from,
                kind: hardware(e),
            }
        }
    };
    if f.from.is_zero() && f.until.is_none() {
        sim
    } else {
        sim.during(f.from, f.until)
    }
}

/// The simulator's configuration for the arm of `config`: one servo per joint with the joint's
/// limits as position limits, powered on at the home pose; the bus settings of `[bus]` and the
/// faults and timing of `[sim]`.
pub fn sim_config(config: &Config) -> Result<SimConfig, SimBusError> {
    let Some(arm) = config.arm() else {
        return Err(
            match config
                .joints()
                .iter()
                .position(|j| j.id.is_none() || j.model.is_none())
            {
                Some(i) => SimBusError::MissingServo { joint: i + 1 },
                None => SimBusError::NoBus,
            },
        );
    };
    let mut servos = Vec::with_capacity(arm.joints().len());
    for (joint, home) in arm.joints().iter().zip(config.home()) {
        let model: Model = joint
            .model
            .name()
            .parse()
            .map_err(|_| SimBusError::NotSimulated {
                joint: joint.joint,
                model: joint.model.name(),
            })?;
        let mut spec = ServoSpec::new(joint.id, model);
        spec.min_position_ticks = u32::try_from(joint.ticks.min).ok();
        spec.max_position_ticks = u32::try_from(joint.ticks.max).ok();
        spec.initial_position_ticks = joint.position_ticks(*home);
        if let Some(sim) = config.sim() {
            spec.firmware = sim
                .firmware_by_id
                .iter()
                .find(|(id, _)| *id == joint.id)
                .map(|&(_, version)| version)
                .or(sim.firmware);
        }
        servos.push(spec);
    }
    let mut out = SimConfig {
        servos,
        ..SimConfig::default()
    };
    if let Some(bus) = config.bus() {
        out.baud = bus.baud;
    }
    out.return_delay_us = arm.settings().return_delay_us;
    if let Some(sim) = config.sim() {
        out.wire_timing = sim.wire_timing;
        if let Some(latency_timer) = sim.ftdi_latency {
            out.adapter = snakectl_sim::Adapter::Ftdi { latency_timer };
        }
        out.seed = sim.seed;
        out.faults = sim.faults.iter().map(fault).collect();
        if let Some(boot_time) = sim.boot_time {
            out.boot_time = boot_time;
        }
    }
    Ok(out)
}

/// The simulators of `config`'s bus, one per port in order: each serves that port's servos,
/// the faults that name one of them or none, and the `disconnect`s of that port or of every
/// port. One port: [`sim_config`] alone.
pub fn sim_configs(config: &Config) -> Result<Vec<SimConfig>, SimBusError> {
    let whole = sim_config(config)?;
    let Some(bus) = config.bus() else {
        return Ok(vec![whole]);
    };
    if bus.ports.len() <= 1 {
        return Ok(vec![whole]);
    }
    let faults: &[Fault] = config.sim().map_or(&[], |s| s.faults.as_slice());
    Ok(bus
        .ports
        .iter()
        .enumerate()
        .map(|(k, port)| {
            let mut one = whole.clone();
            one.servos.retain(|s| port.ids.contains(&s.id));
            one.seed = whole.seed.wrapping_add(k as u64);
            one.faults = faults
                .iter()
                .filter(|f| f.id.is_none_or(|id| port.ids.contains(&id)))
                .filter(|f| f.port.is_none_or(|p| p == k))
                .map(fault)
                .collect();
            one
        })
        .collect())
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
    fn two_ports_make_two_simulators_each_with_its_servos_and_faults() {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml"))
            .unwrap()
            + "\n[[sim.fault]]\nkind = \"silent\"\nid = 9\nat_s = 1.0\n"
            + "\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.1\n"
            + "\n[[sim.fault]]\nkind = \"disconnect\"\nport = 1\nat_s = 2.0\n"
            + "\n[[bus.ports]]\nids = [1, 2, 3, 4, 5, 6]\n"
            + "\n[[bus.ports]]\nids = [7, 8, 9, 10, 11, 12]\n";
        let config = Config::from_str(&text, "sim.toml").unwrap();
        let sims = sim_configs(&config).unwrap();
        assert_eq!(sims.len(), 2);
        let ids = |k: usize| sims[k].servos.iter().map(|s| s.id).collect::<Vec<_>>();
        assert_eq!(ids(0), [1, 2, 3, 4, 5, 6]);
        assert_eq!(ids(1), [7, 8, 9, 10, 11, 12]);
        let s = std::time::Duration::from_secs_f64;
        let drop = SimFault::DropReplies {
            id: None,
            fraction: 0.1,
        };
        assert_eq!(
            sims[0].faults,
            [drop.clone(), SimFault::Disconnect.during(s(2.0), None)]
        );
        assert_eq!(
            sims[1].faults,
            [SimFault::Silent { id: 9, at: s(1.0) }, drop]
        );
        // One port: the whole chain, as `sim_config` makes it.
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
        let one = Config::load(path).unwrap();
        assert_eq!(sim_configs(&one).unwrap(), [sim_config(&one).unwrap()]);
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
            + "\n[[sim.fault]]\nkind = \"drop\"\nfraction = 0.3\n"
            + "\n[[sim.fault]]\nkind = \"disconnect\"\nat_s = 0.5\nuntil_s = 1.5\n"
            + "\n[[sim.fault]]\nkind = \"disconnect\"\nat_s = 4.0\n";
        let config = Config::from_str(&text, "sim.toml").unwrap();
        let sim = sim_config(&config).unwrap();
        let s = std::time::Duration::from_secs_f64;
        let base = sim.faults.len() - 8;
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
                .during(std::time::Duration::ZERO, Some(s(1.5))),
                SimFault::ExtraLatency {
                    id: None,
                    latency: std::time::Duration::from_micros(700)
                }
                .during(s(1.0), Some(s(4.0))),
                SimFault::Silent { id: 5, at: s(2.5) }
                    .during(std::time::Duration::ZERO, Some(s(3.0))),
                SimFault::Silent { id: 6, at: s(1.0) },
                SimFault::DropReplies {
                    id: None,
                    fraction: 0.3
                },
                SimFault::Disconnect.during(s(0.5), Some(s(1.5))),
                SimFault::Disconnect.during(s(4.0), None),
            ]
        );
        // And the simulator accepts them.
        let clock = std::sync::Arc::new(snakectl_sim::ManualClock::new());
        snakectl_sim::Simulator::new(sim, clock).unwrap();
    }
}
