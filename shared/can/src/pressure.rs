//! CiA 404, the pressure transducers: a process value as INT16 (0x7130),
//! INT32 (0x9130) or REAL32 (0x6130), sub-index = channel, with its
//! decimal digits (0x6132) and physical unit (0x6131), converted to Pa.

use serde::{Deserialize, Serialize};

use crate::CanError;

pub mod object {
    pub(crate) const PROCESS_VALUE_REAL32: u16 = 0x6130;
    pub const PHYSICAL_UNIT: u16 = 0x6131;
    pub const DECIMAL_DIGITS: u16 = 0x6132;
    pub const STATUS: u16 = 0x6150;
    pub(crate) const PROCESS_VALUE_INT16: u16 = 0x7130;
    pub(crate) const PROCESS_VALUE_INT32: u16 = 0x9130;
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ValueType {
    Int16,
    Int32,
    Real32,
}

impl ValueType {
    pub(crate) fn object(self) -> u16 {
        match self {
            Self::Int16 => object::PROCESS_VALUE_INT16,
            Self::Int32 => object::PROCESS_VALUE_INT32,
            Self::Real32 => object::PROCESS_VALUE_REAL32,
        }
    }

    pub fn bits(self) -> u8 {
        match self {
            Self::Int16 => 16,
            Self::Int32 | Self::Real32 => 32,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum PressureUnit {
    #[serde(rename = "Pa")]
    Pascal,
    #[serde(rename = "kPa")]
    KiloPascal,
    #[serde(rename = "MPa")]
    MegaPascal,
    #[serde(rename = "bar")]
    Bar,
    #[serde(rename = "mbar")]
    MilliBar,
}

impl PressureUnit {
    pub(crate) fn pascal(self) -> f64 {
        match self {
            Self::Pascal => 1.0,
            Self::KiloPascal => 1e3,
            Self::MegaPascal => 1e6,
            Self::Bar => 1e5,
            Self::MilliBar => 1e2,
        }
    }

    /// Object 0x6131 as CiA 303-2 codes it: prefix in bits 24–31, unit in
    /// bits 16–23 (Pa 0x22, bar 0x4E).
    pub fn code(self) -> u32 {
        let (prefix, unit): (u32, u32) = match self {
            Self::Pascal => (0x00, 0x22),
            Self::KiloPascal => (0x03, 0x22),
            Self::MegaPascal => (0x06, 0x22),
            Self::Bar => (0x00, 0x4E),
            Self::MilliBar => (0xFD, 0x4E),
        };
        (prefix << 24) | (unit << 16)
    }

    pub fn from_code(code: u32) -> Option<Self> {
        [
            Self::Pascal,
            Self::KiloPascal,
            Self::MegaPascal,
            Self::Bar,
            Self::MilliBar,
        ]
        .into_iter()
        .find(|u| u.code() == code & 0xFFFF_0000)
    }
}

/// One transducer channel's encoding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressureScale {
    pub value_type: ValueType,
    /// Object 0x6132: the integer value is in units of 10^-digits.
    pub decimal_digits: u8,
    pub unit: PressureUnit,
}

impl Default for PressureScale {
    /// 0.1 bar a step in an INT16: ±3276.7 bar.
    fn default() -> Self {
        Self {
            value_type: ValueType::Int16,
            decimal_digits: 1,
            unit: PressureUnit::Bar,
        }
    }
}

impl PressureScale {
    fn step(&self) -> f64 {
        match self.value_type {
            ValueType::Real32 => self.unit.pascal(),
            _ => self.unit.pascal() / 10f64.powi(i32::from(self.decimal_digits)),
        }
    }

    /// The pressure in Pa from the raw value a PDO carries.
    pub(crate) fn pascal(&self, raw: u64) -> Result<f64, CanError> {
        let value = match self.value_type {
            ValueType::Int16 => f64::from(raw as u16 as i16),
            ValueType::Int32 => f64::from(raw as u32 as i32),
            ValueType::Real32 => f64::from(f32::from_bits(raw as u32)),
        };
        if !value.is_finite() {
            return Err(CanError::Malformed {
                cob_id: 0,
                what: "pressure process value",
                reason: format!("{value} is not a pressure"),
            });
        }
        Ok(value * self.step())
    }

    /// The raw value a transducer sends for `pascal`: rounded to its step,
    /// saturated at its range as a real transducer's output is.
    pub fn raw(&self, pascal: f64) -> u64 {
        let value = if pascal.is_finite() { pascal / self.step() } else { 0.0 };
        match self.value_type {
            ValueType::Int16 => u64::from(value.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16 as u16),
            ValueType::Int32 => u64::from(value.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32 as u32),
            ValueType::Real32 => u64::from((value as f32).to_bits()),
        }
    }

    /// One step, Pa.
    pub fn resolution(&self) -> f64 {
        self.step()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn process_values_become_pascal() {
        let bar = PressureScale::default();
        // 123.4 bar as INT16 with one decimal digit: 1234.
        assert_eq!(bar.raw(123.4e5), 1234);
        assert!((bar.pascal(1234).expect("value") - 123.4e5).abs() < 1e-6);
        assert!((bar.pascal(u64::from((-15i16) as u16)).expect("value") + 1.5e5).abs() < 1e-6);
        assert_eq!(bar.raw(1e9), 0x7FFF, "saturates at the range");
        let kpa = PressureScale {
            value_type: ValueType::Int32,
            decimal_digits: 0,
            unit: PressureUnit::KiloPascal,
        };
        assert_eq!(kpa.pascal(u64::from(20_000u32)).expect("value"), 20e6);
        let real = PressureScale {
            value_type: ValueType::Real32,
            decimal_digits: 0,
            unit: PressureUnit::MegaPascal,
        };
        assert_eq!(real.pascal(u64::from(12.5f32.to_bits())).expect("value"), 12.5e6);
        assert!(real.pascal(u64::from(f32::NAN.to_bits())).is_err());
    }

    #[test]
    fn units_carry_their_cia_303_codes() {
        assert_eq!(PressureUnit::Bar.code(), 0x004E_0000);
        assert_eq!(PressureUnit::KiloPascal.code(), 0x0322_0000);
        assert_eq!(PressureUnit::from_code(0xFD4E_0000), Some(PressureUnit::MilliBar));
        assert_eq!(PressureUnit::from_code(0x0001_0000), None);
    }
}
