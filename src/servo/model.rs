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
}

const fn model(
    name: &'static str,
    number: u16,
    current: CurrentUnit,
    indirect_data: Option<u16>,
    fast_read: Option<u8>,
) -> ServoModel {
    ServoModel {
        name,
        number,
        current,
        indirect_data,
        fast_read,
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
/// firmware that answers Fast Sync Read.
pub const MODELS: [ServoModel; 12] = [
    model("XH430-W210", 1000, MA_2_69, X430_DATA, X430_FAST),
    model("XH430-W350", 1010, MA_2_69, X430_DATA, X430_FAST),
    model("XM430-W350", 1020, MA_2_69, X430_DATA, X430_FAST),
    model("XM430-W210", 1030, MA_2_69, X430_DATA, X430_FAST),
    model("XL430-W250", 1060, LOAD, X430_DATA, X430_FAST),
    model("XC430-W150", 1070, LOAD, X430_DATA, X430_FAST),
    model("XC430-W240", 1080, LOAD, X430_DATA, X430_FAST),
    model("2XL430-W250", 1090, LOAD, X430_DATA, NO_FAST),
    model("XM540-W270", 1120, MA_2_69, X430_DATA, X540_FAST),
    model("XM540-W150", 1130, MA_2_69, X430_DATA, X540_FAST),
    model("XL330-M077", 1190, MA_1, X330_DATA, X330_FAST),
    model("XL330-M288", 1200, MA_1, X330_DATA, X330_FAST),
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
    fn fast_sync_read_follows_the_emanual_firmware_rule() {
        let supports =
            |name, fw| ServoModel::from_name(name).is_some_and(|m| m.supports_fast_read(fw));
        assert!(supports("XL430-W250", 45) && !supports("XL430-W250", 44));
        assert!(supports("XM540-W270", 45) && !supports("XM540-W270", 44));
        assert!(supports("XL330-M288", 46) && !supports("XL330-M288", 45));
        assert!(!supports("2XL430-W250", 255));
    }
}
