//! The servo models this program knows: one table, read by the config (model names), bring-up
//! (model numbers), `scan` (names of what answers) and the units (what Present Current counts).
//! Adding a model is one row here (and, to simulate it, one in the simulator's own table).

use super::units::CurrentUnit;

/// A Dynamixel X-series model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoModel {
    name: &'static str,
    number: u16,
    current: CurrentUnit,
    indirect_data: Option<u16>,
}

const fn model(
    name: &'static str,
    number: u16,
    current: CurrentUnit,
    indirect_data: Option<u16>,
) -> ServoModel {
    ServoModel {
        name,
        number,
        current,
        indirect_data,
    }
}

const LOAD: CurrentUnit = CurrentUnit::LoadPermille;
const MA_2_69: CurrentUnit = CurrentUnit::MilliAmps(2.69);
const MA_1: CurrentUnit = CurrentUnit::MilliAmps(1.0);
/// Indirect Data 1 of the X430/X540 models (28 slots from Indirect Address 1 at 168).
const X430_DATA: Option<u16> = Some(224);
/// Indirect Data 1 of the XL330 models (20 slots from Indirect Address 1 at 168).
const X330_DATA: Option<u16> = Some(208);

/// Every known model: e-manual name, Model Number (register 0), Present Current's unit, the
/// address of Indirect Data 1 (every one of them has Indirect Address 1 at 168).
pub const MODELS: [ServoModel; 12] = [
    model("XH430-W210", 1000, MA_2_69, X430_DATA),
    model("XH430-W350", 1010, MA_2_69, X430_DATA),
    model("XM430-W350", 1020, MA_2_69, X430_DATA),
    model("XM430-W210", 1030, MA_2_69, X430_DATA),
    model("XL430-W250", 1060, LOAD, X430_DATA),
    model("XC430-W150", 1070, LOAD, X430_DATA),
    model("XC430-W240", 1080, LOAD, X430_DATA),
    model("2XL430-W250", 1090, LOAD, X430_DATA),
    model("XM540-W270", 1120, MA_2_69, X430_DATA),
    model("XM540-W150", 1130, MA_2_69, X430_DATA),
    model("XL330-M077", 1190, MA_1, X330_DATA),
    model("XL330-M288", 1200, MA_1, X330_DATA),
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
}
