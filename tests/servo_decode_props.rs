//! The decoding of status parameters (`Register::decode`, `ServoState::decode`) on data of any
//! length: never a panic; a block of the wrong length is refused as malformed, naming the servo;
//! a block of the right length gives the position at its place in the span.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use proptest::prelude::*;
use snakectl::servo::{ErrorClass, Fields, Register, ServoError, ServoState};

const REGISTERS: [Register; 8] = [
    Register::TorqueEnable,
    Register::BusWatchdog,
    Register::GoalPosition,
    Register::PresentCurrent,
    Register::PresentVelocity,
    Register::PresentPosition,
    Register::PresentInputVoltage,
    Register::PresentTemperature,
];

fn fields() -> impl Strategy<Value = Fields> {
    (any::<bool>(), any::<bool>(), any::<bool>(), any::<bool>()).prop_map(
        |(velocity, current, voltage, temperature)| Fields {
            velocity,
            current,
            voltage,
            temperature,
        },
    )
}

proptest! {
    #[test]
    fn a_register_decodes_any_bytes_without_panicking(
        index in 0..REGISTERS.len(),
        bytes in prop::collection::vec(any::<u8>(), 0..12),
    ) {
        let r = REGISTERS[index];
        let n = usize::from(r.size());
        match r.decode(&bytes) {
            None => prop_assert!(bytes.len() < n),
            Some(v) => {
                prop_assert!(bytes.len() >= n);
                // The value encodes back to the register's bytes.
                prop_assert_eq!(&v.to_le_bytes()[..n], &bytes[..n]);
            }
        }
    }

    #[test]
    fn a_state_decodes_data_of_any_length_without_panicking(
        id in any::<u8>(),
        data in prop::collection::vec(any::<u8>(), 0..64),
        alert in any::<bool>(),
        fields in fields(),
    ) {
        let (start, len) = fields.span();
        match ServoState::decode(id, &data, alert, fields) {
            Ok(state) => {
                prop_assert_eq!(data.len(), usize::from(len));
                prop_assert_eq!(state.id, id);
                prop_assert_eq!(state.alert, alert);
                let at = usize::from(Register::PresentPosition.address() - start);
                let position = i32::from_le_bytes(data[at..at + 4].try_into().unwrap());
                prop_assert_eq!(state.position_ticks, position);
                prop_assert_eq!(state.velocity.is_some(), fields.velocity);
                prop_assert_eq!(state.temperature_c.is_some(), fields.temperature);
            }
            Err(e) => {
                prop_assert_ne!(data.len(), usize::from(len));
                prop_assert!(matches!(e, ServoError::Malformed { .. }), "{e:?}");
                prop_assert_eq!(e.id(), Some(id));
                prop_assert_eq!(e.class(), ErrorClass::Transient);
            }
        }
    }

    #[test]
    fn a_state_decodes_every_block_of_the_right_length(
        id in any::<u8>(),
        fields in fields(),
        seed in prop::collection::vec(any::<u8>(), 21),
    ) {
        let len = usize::from(fields.span().1);
        prop_assert!(ServoState::decode(id, &seed[..len], false, fields).is_ok());
    }
}
