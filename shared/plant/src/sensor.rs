//! The sensors: an incremental encoder on the actuator (with the
//! `quantization` and `backlash` effects acting here) and two pressure
//! transducers with range and white noise.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::effects::{Backlash, Effects, Quantization};
use crate::{PlantError, PlantState, SensorParams};

/// What the sensors report, SI units, before any filtering.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawReading {
    /// Encoder angle, rad.
    pub angle: f64,
    /// Chamber pressures, Pa, within the transducers' range.
    pub p_a: f64,
    pub p_b: f64,
}

/// The sensor models, deterministic for a given seed.
#[derive(Debug, Clone)]
pub struct SensorModel {
    params: SensorParams,
    quantization: Quantization,
    backlash: Option<Backlash>,
    encoder_shaft: f64,
    rng: ChaCha8Rng,
    noise: Option<Normal<f64>>,
}

impl SensorModel {
    pub fn new(params: SensorParams, effects: &Effects, seed: u64) -> Result<Self, PlantError> {
        params.validate()?;
        let quantization = effects.quantization.unwrap_or(Quantization {
            step: params.encoder_step(),
        });
        let noise = if params.pressure_noise_std > 0.0 {
            Some(
                Normal::new(0.0, params.pressure_noise_std)
                    .map_err(|_| PlantError::invalid("pressure_noise_std", params.pressure_noise_std, "invalid"))?,
            )
        } else {
            None
        };
        Ok(Self {
            params,
            quantization,
            backlash: effects.backlash,
            encoder_shaft: 0.0,
            rng: ChaCha8Rng::seed_from_u64(seed),
            noise,
        })
    }

    /// Aligns the encoder's shaft with the actuator, as after homing.
    pub fn home(&mut self, angle: f64) {
        self.encoder_shaft = angle;
    }

    pub fn encoder_step(&self) -> f64 {
        self.quantization.step
    }

    pub fn read(&mut self, state: &PlantState) -> RawReading {
        self.encoder_shaft = match self.backlash {
            Some(backlash) => backlash.follow(state.angle, self.encoder_shaft),
            None => state.angle,
        };
        let angle = self.quantization.quantize(self.encoder_shaft);
        let p_a = self.transduce(state.p_a);
        let p_b = self.transduce(state.p_b);
        RawReading { angle, p_a, p_b }
    }

    fn transduce(&mut self, pressure: f64) -> f64 {
        let noise = match &self.noise {
            Some(normal) => normal.sample(&mut self.rng),
            None => 0.0,
        };
        (pressure + noise).clamp(self.params.pressure_min, self.params.pressure_max)
    }
}
