//! CiA 406, the angle encoder: the position value (0x6004, 32 bits) in
//! TPDO1, counted in steps of 1/`counts_per_revolution` turn from the
//! preset. The rotator turns without end, so the count is read as a
//! wrapping 32-bit number: angles are continuous across the wrap.

pub mod object {
    pub const COUNTS_PER_REVOLUTION: u16 = 0x6001;
    pub const PRESET: u16 = 0x6003;
    pub const POSITION: u16 = 0x6004;
    pub const SPEED: u16 = 0x6030;
    pub const CYCLIC_TIMER: u16 = 0x6200;
}

/// How counts become radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EncoderScale {
    /// Measuring steps per turn (object 0x6001).
    pub counts_per_revolution: u32,
    /// The count at angle zero.
    pub zero_count: i32,
}

impl Default for EncoderScale {
    fn default() -> Self {
        Self {
            counts_per_revolution: 16384,
            zero_count: 0,
        }
    }
}

impl EncoderScale {
    pub fn angle(&self, position: u32) -> f64 {
        let steps = (position as i32).wrapping_sub(self.zero_count);
        f64::from(steps) * std::f64::consts::TAU / f64::from(self.counts_per_revolution.max(1))
    }

    /// The count an encoder reports at `angle`: whole steps, truncated
    /// toward minus infinity as an incremental count is.
    pub fn position(&self, angle: f64) -> u32 {
        let steps = (angle / std::f64::consts::TAU * f64::from(self.counts_per_revolution)).floor();
        let steps = if steps.is_finite() { steps as i64 } else { 0 };
        (steps as i32).wrapping_add(self.zero_count) as u32
    }

    /// One step, rad.
    pub fn resolution(&self) -> f64 {
        std::f64::consts::TAU / f64::from(self.counts_per_revolution.max(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_become_radians_across_the_wrap() {
        let scale = EncoderScale {
            counts_per_revolution: 4096,
            zero_count: 100,
        };
        assert_eq!(scale.angle(100), 0.0);
        assert!((scale.angle(100 + 1024) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((scale.angle(99) + scale.resolution()).abs() < 1e-12);
        let near_wrap = EncoderScale {
            counts_per_revolution: 4096,
            zero_count: i32::MAX,
        };
        assert!((near_wrap.angle(near_wrap.position(0.3)) - 0.3).abs() <= near_wrap.resolution());
        assert!((near_wrap.angle(near_wrap.position(-0.3)) + 0.3).abs() <= near_wrap.resolution());
        assert_eq!(scale.position(f64::NAN), 100);
    }

    #[test]
    fn the_count_is_truncated_to_whole_steps() {
        let scale = EncoderScale::default();
        let step = scale.resolution();
        assert_eq!(scale.position(0.99 * step), 0);
        assert_eq!(scale.position(-0.01 * step) as i32, -1);
    }
}
