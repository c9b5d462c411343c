//! The servo models this program knows: one table, read by the config (model names), bring-up
//! (model numbers), `scan` (names of what answers), the units (what Present Current counts) and
//! which firmware speaks Fast Sync Read. Adding a model is one row here (and, to simulate it, one
//! in the simulator's own table).

use super::units::CurrentUnit;

/// A Dynamixel X-series model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoModel {
    name: &'static str,
    number: u16,
    current: CurrentUnit,
    indirect_data: Option<u16>,
    fast_read: Option<u8>,
    rated: Rated,
}

/// Stall torque, N·m, and no-load speed, rev/min, at the model's recommended input voltage,
/// from the e-manual's X-series specification tables.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Rated {
    stall_torque_nm: f64,
    no_load_rpm: f64,
}

/// [`Rated`] at the recommended voltage.
const fn rated(stall_torque_nm: f64, no_load_rpm: f64) -> Rated {
    Rated {
        stall_torque_nm,
        no_load_rpm,
    }
}

const fn model(
    name: &'static str,
    number: u16,
    current: CurrentUnit,
    indirect_data: Option<u16>,
    fast_read: Option<u8>,
    rated: Rated,
) -> ServoModel {
    ServoModel {
        name,
        number,
        current,
        indirect_data,
        fast_read,
        rated,
    }
}

const LOAD: CurrentUnit = CurrentUnit::LoadPermille;
const MA_2_69: CurrentUnit = CurrentUnit::MilliAmps(2.69);
const MA_1: CurrentUnit = CurrentUnit::MilliAmps(1.0);
/// Indirect Data 1 of the X430/X540 models (28 slots from Indirect Address 1 at 168).
const X430_DATA: Option<u16> = Some(224);
/// Indirect Data 1 of the XL330 models (20 slots from Indirect Address 1 at 168).
const X330_DATA: Option<u16> = Some(208);

/// Fast Sync Read (0x8A), per the e-manual's Protocol 2.0 page: X430 and X540 from firmware 45
/// (never the dual 2XL/2XC), X330 from firmware 46.
const X430_FAST: Option<u8> = Some(45);
const X540_FAST: Option<u8> = Some(45);
const X330_FAST: Option<u8> = Some(46);
const NO_FAST: Option<u8> = None;

/// Every known model: e-manual name, Model Number (register 0), Present Current's unit, the
/// address of Indirect Data 1 (every one of them has Indirect Address 1 at 168), the first
/// firmware that answers Fast Sync Read, and stall torque and no-load speed at the recommended
/// voltage (12 V for XH/XM/XC, 11.1 V for XL430 and 2XL430, 5 V for XL330).
#[rustfmt::skip]
pub const MODELS: [ServoModel; 12] = [
    model("XH430-W210", 1000, MA_2_69, X430_DATA, X430_FAST, rated(2.5, 50.0)),
    model("XH430-W350", 1010, MA_2_69, X430_DATA, X430_FAST, rated(3.4, 30.0)),
    model("XM430-W350", 1020, MA_2_69, X430_DATA, X430_FAST, rated(4.1, 46.0)),
    model("XM430-W210", 1030, MA_2_69, X430_DATA, X430_FAST, rated(3.0, 77.0)),
    model("XL430-W250", 1060, LOAD, X430_DATA, X430_FAST, rated(1.4, 57.0)),
    model("XC430-W150", 1070, LOAD, X430_DATA, X430_FAST, rated(1.6, 106.0)),
    model("XC430-W240", 1080, LOAD, X430_DATA, X430_FAST, rated(1.9, 70.0)),
    model("2XL430-W250", 1090, LOAD, X430_DATA, NO_FAST, rated(1.4, 57.0)),
    model("XM540-W270", 1120, MA_2_69, X430_DATA, X540_FAST, rated(10.6, 30.0)),
    model("XM540-W150", 1130, MA_2_69, X430_DATA, X540_FAST, rated(7.3, 53.0)),
    model("XL330-M077", 1190, MA_1, X330_DATA, X330_FAST, rated(0.215, 383.0)),
    model("XL330-M288", 1200, MA_1, X330_DATA, X330_FAST, rated(0.52, 103.0)),
];

impl ServoModel {
    /// The model with this e-manual name (exact spelling, e.g. `"XL430-W250"`).
    pub fn from_name(name: &str) -> Option<Self> {
        MODELS.into_iter().find(|m| m.name == name)
    }

    /// The model that reports this Model Number.
    pub fn from_number(number: u16) -> Option<Self> {
        MODELS.into_iter().find(|m| m.number == number)
    }

    /// The e-manual name.
    pub fn name(self) -> &'static str {
        self.name
    }

    /// The value of the Model Number register (address 0).
    pub fn model_number(self) -> u16 {
        self.number
    }

    /// What one unit of Present Current (or Present Load) means on this model.
    pub fn current_unit(self) -> CurrentUnit {
        self.current
    }

    /// The address of Indirect Data 1, where the registers mapped by Indirect Address 1
    /// onward (from 168) are read; `None` for a model without indirect addressing.
    pub fn indirect_data(self) -> Option<u16> {
        self.indirect_data
    }

    /// The first Firmware Version (register 6) that answers Fast Sync Read; `None` when no
    /// firmware of this model does.
    pub fn fast_read_firmware(self) -> Option<u8> {
        self.fast_read
    }

    /// Stall torque at the recommended input voltage, N·m (the e-manual's figure).
    pub fn stall_torque_nm(self) -> f64 {
        self.rated.stall_torque_nm
    }

    /// No-load speed at the recommended input voltage, rad/s (the e-manual's rev/min).
    pub fn no_load_speed_rad_s(self) -> f64 {
        self.rated.no_load_rpm * std::f64::consts::TAU / 60.0
    }

    /// Whether this model at `firmware` answers Fast Sync Read.
    pub fn supports_fast_read(self, firmware: u8) -> bool {
        self.fast_read.is_some_and(|first| firmware >= first)
    }
}

impl std::fmt::Display for ServoModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

/// The name of a Model Number, if known.
pub fn model_name(number: u16) -> Option<&'static str> {
    ServoModel::from_number(number).map(ServoModel::name)
}

/// Every known model's name, for error messages.
pub fn model_names() -> String {
    MODELS.map(ServoModel::name).join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    #[test]
    fn names_and_numbers_are_unique_and_round_trip() {
        for (i, m) in MODELS.iter().enumerate() {
            assert_eq!(ServoModel::from_name(m.name()), Some(*m));
            assert_eq!(ServoModel::from_number(m.model_number()), Some(*m));
            for other in &MODELS[..i] {
                assert_ne!(other.name, m.name);
                assert_ne!(other.number, m.number);
            }
        }
    }

    #[test]
    fn numbers_and_units_from_the_emanual() {
        // Model Numbers as the e-manual's control tables give them.
        assert_eq!(model_name(1060), Some("XL430-W250"));
        assert_eq!(model_name(1020), Some("XM430-W350"));
        assert_eq!(model_name(1200), Some("XL330-M288"));
        assert_eq!(model_name(1), None);
        // XL430: Present Load in 0.1 %; XM430: 2.69 mA a unit; XL330: 1 mA.
        let unit = |n| ServoModel::from_number(n).map(ServoModel::current_unit);
        assert_eq!(unit(1060), Some(CurrentUnit::LoadPermille));
        assert_eq!(unit(1020), Some(CurrentUnit::MilliAmps(2.69)));
        assert_eq!(unit(1200), Some(CurrentUnit::MilliAmps(1.0)));
        assert!(ServoModel::from_name("xl430-w250").is_none());
    }

    #[test]
    #[allow(clippy::unwrap_used)]
    fn rated_figures_from_the_emanual() {
        let m = |name| ServoModel::from_name(name).unwrap();
        // XL430-W250 at 11.1 V: 1.4 N·m, 57 rev/min = 57 * 2 pi / 60 rad/s.
        assert_eq!(m("XL430-W250").stall_torque_nm(), 1.4);
        assert!((m("XL430-W250").no_load_speed_rad_s() - 5.969026041820607).abs() < 1e-12);
        // XM430-W350 at 12 V: 4.1 N·m, 46 rev/min.
        assert_eq!(m("XM430-W350").stall_torque_nm(), 4.1);
        assert!((m("XM430-W350").no_load_speed_rad_s() - 46.0 * TAU / 60.0).abs() < 1e-12);
        for model in MODELS {
            assert!(model.stall_torque_nm() > 0.0 && model.no_load_speed_rad_s() > 0.0);
        }
    }

    #[test]
    fn fast_sync_read_follows_the_emanual_firmware_rule() {
        let supports =
            |name, fw| ServoModel::from_name(name).is_some_and(|m| m.supports_fast_read(fw));
        assert!(supports("XL430-W250", 45) && !supports("XL430-W250", 44));
        assert!(supports("XM540-W270", 45) && !supports("XM540-W270", 44));
        assert!(supports("XL330-M288", 46) && !supports("XL330-M288", 45));
        assert!(!supports("2XL430-W250", 255));
    }
}
