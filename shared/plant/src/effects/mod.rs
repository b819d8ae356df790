//! The effect catalog: physical effects outside the papers' linear baseline,
//! each one block with named parameters in physical units. The same blocks
//! switch an effect on in the simulated plant and add it to a model under
//! identification, so the names and keys here are the command line's and the
//! JSON's.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

use crate::PlantError;

mod kind;
pub use kind::{EffectKind, FitRange, FitStarts, ParamSpec, StartScale};

/// Spool overlap: no flow while the spool is within `width` of the band's
/// centre, `offset` (a real valve's band is seldom centred on zero: its
/// centre is the null offset, the command that holds a hanging load still).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deadzone {
    /// Half-width of the overlap, command units.
    pub width: f64,
    /// Centre of the overlap, command units.
    pub offset: f64,
}

impl Deadzone {
    /// The effective opening: the spool travel beyond the overlap.
    #[inline]
    pub fn opening(&self, spool: f64) -> f64 {
        let from_centre = spool - self.offset;
        match self.side(spool) {
            std::cmp::Ordering::Greater => from_centre - self.width,
            std::cmp::Ordering::Less => from_centre + self.width,
            std::cmp::Ordering::Equal => 0.0,
        }
    }

    /// Where the spool is against the overlap: below it, within it (its
    /// edges included), above it.
    #[inline]
    pub fn side(&self, spool: f64) -> std::cmp::Ordering {
        let from_centre = spool - self.offset;
        if from_centre > self.width {
            std::cmp::Ordering::Greater
        } else if from_centre < -self.width {
            std::cmp::Ordering::Less
        } else {
            std::cmp::Ordering::Equal
        }
    }
}

/// The piece of [`Effects::valve_band`] the spool is on: 0 below the
/// band, 1 inside it (or everywhere, without a band), 2 above.
#[inline]
pub fn valve_piece(band: Option<Deadzone>, spool: f64) -> usize {
    match band.map(|band| band.side(spool)) {
        Some(std::cmp::Ordering::Less) => 0,
        None | Some(std::cmp::Ordering::Equal) => 1,
        Some(std::cmp::Ordering::Greater) => 2,
    }
}

/// Where to take an affine map's differences on each piece of `band`: a
/// spool on the piece and a move that stays on it, below, inside (none
/// for a band of no width) and above; without a band, one piece about 0.
pub fn valve_piece_probes(band: Option<Deadzone>) -> [Option<(f64, f64)>; 3] {
    match band {
        Some(Deadzone {
            width: half_width,
            offset: centre,
        }) => [
            Some((centre - half_width - 1.0, -1.0)),
            (half_width > 0.0).then_some((centre, 0.5 * half_width)),
            Some((centre + half_width + 1.0, 1.0)),
        ],
        None => [None, Some((0.0, 1.0)), None],
    }
}

/// Spool travel limit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Saturation {
    /// Largest spool travel, command units.
    pub limit: f64,
}

impl Saturation {
    #[inline]
    pub fn clamp(&self, spool: f64) -> f64 {
        spool.clamp(-self.limit, self.limit)
    }
}

/// A pure delay of the valve command (bus, electronics, pilot stage).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeDelay {
    /// Seconds; realized at the integration step's resolution.
    pub delay_s: f64,
}

/// Flow gain differs with the direction of the spool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AsymmetricGain {
    /// Flow gain for negative openings divided by that for positive ones.
    pub ratio: f64,
}

impl AsymmetricGain {
    #[inline]
    pub(crate) fn gain_factor(&self, opening: f64) -> f64 {
        if opening < 0.0 {
            self.ratio
        } else {
            1.0
        }
    }
}

/// Turbulent orifice flow: the flow-gain term grows with the square root of
/// the pressure drop across the metering edge instead of being constant.
/// It equals the linearized flow gain at a drop of half the supply pressure,
/// the operating point the linearization of eq. (9) is made at. The valve's
/// centre-leakage term (K_c) stays, so the neutral pressures stay defined.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrificeFlow;

impl OrificeFlow {
    /// Below this fraction of the nominal drop the root is replaced by a
    /// line through the origin, keeping the flow's slope finite at zero drop.
    const LAMINAR_FRACTION: f64 = 0.01;

    /// √(drop / nominal_drop), regularized near zero and zero for a negative drop.
    #[inline]
    pub(crate) fn drop_factor(drop: f64, nominal_drop: f64) -> f64 {
        let r = (drop / nominal_drop).max(0.0);
        if r < Self::LAMINAR_FRACTION {
            r / Self::LAMINAR_FRACTION.sqrt()
        } else {
            r.sqrt()
        }
    }
}

/// Coulomb friction with a Stribeck breakaway, stick-slip capable.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoulombFriction {
    /// Sliding (Coulomb) friction torque, N·m.
    pub coulomb: f64,
    /// Breakaway (static) friction torque, N·m; at least `coulomb`.
    pub breakaway: f64,
    /// Stribeck velocity, rad/s: how fast friction falls from breakaway to Coulomb.
    pub stribeck_velocity: f64,
}

impl CoulombFriction {
    /// Magnitude of the sliding friction at speed `speed` (≥ 0).
    #[inline]
    pub fn sliding_level(&self, speed: f64) -> f64 {
        let v = speed / self.stribeck_velocity;
        // Beyond six Stribeck velocities the excess is below 1e-15 of it:
        // not worth an exp on every step of a simulation.
        if v * v > 36.0 {
            return self.coulomb;
        }
        self.coulomb + (self.breakaway - self.coulomb) * (-v * v).exp()
    }
}

/// A load torque ∝ sin(θ − offset), as gravity gives an off-centre load on a
/// tilted rotator or a crane link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GravityLoad {
    /// N·m at the worst angle.
    pub amplitude: f64,
    /// rad: the angle at which the load torque is zero, rising.
    pub offset: f64,
}

impl GravityLoad {
    /// The torque the load applies against positive rotation.
    #[inline]
    pub fn torque(&self, angle: f64) -> f64 {
        self.amplitude * (angle - self.offset).sin()
    }
}

/// Play between the load and the encoder: the encoder's shaft follows only
/// once the play is taken up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Backlash {
    /// Total play, rad.
    pub width: f64,
}

impl Backlash {
    /// The follower's new position given the driver's, from the previous one.
    #[inline]
    pub fn follow(&self, driver: f64, follower: f64) -> f64 {
        let half = 0.5 * self.width;
        if driver - follower > half {
            driver - half
        } else if follower - driver > half {
            driver + half
        } else {
            follower
        }
    }
}

/// A coarse angle sensor: the reading is the angle rounded to `step`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quantization {
    /// Encoder step, rad.
    pub step: f64,
}

impl Quantization {
    #[inline]
    pub fn quantize(&self, angle: f64) -> f64 {
        Self::nearest_count(angle / self.step) * self.step
    }

    /// The whole number of steps nearest `counts`, half away from zero.
    #[inline]
    pub fn nearest_count(counts: f64) -> f64 {
        // `f64::round` is a library call on the baseline x86-64 target (its
        // instruction needs SSE4.1), and model identification quantizes
        // hundreds of millions of samples. Adding and taking away 2^52
        // rounds to the nearest whole number (ties to even), and a tie
        // rounded down is moved up: arithmetic and selects only, with no
        // branch or integer conversion, so blocks of samples round
        // together. From 2^52 on every f64 is whole; NaN and infinities
        // pass through.
        const WHOLE_FROM: f64 = 4_503_599_627_370_496.0;
        let magnitude = counts.abs();
        let even = (magnitude + WHOLE_FROM) - WHOLE_FROM;
        let nearest = if magnitude - even == 0.5 { even + 1.0 } else { even };
        let nearest = if magnitude < WHOLE_FROM { nearest } else { magnitude };
        nearest.copysign(counts)
    }
}

/// A compliant coupling between actuator and load: the crane paper's
/// structural vibration. The inertia splits into a rotor part and a load part.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadFlexibility {
    /// Coupling stiffness, N·m/rad.
    pub stiffness: f64,
    /// Coupling damping, N·m·s/rad.
    pub damping: f64,
    /// Fraction of the plant's inertia on the load side of the coupling.
    pub load_fraction: f64,
}

impl LoadFlexibility {
    /// The coupling torque on the load: positive when the actuator leads.
    #[inline]
    pub(crate) fn coupling_torque(&self, twist: f64, twist_rate: f64) -> f64 {
        self.stiffness * twist + self.damping * twist_rate
    }
}

/// An effect switched on, with its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Effect {
    Deadzone(Deadzone),
    Saturation(Saturation),
    TimeDelay(TimeDelay),
    AsymmetricGain(AsymmetricGain),
    OrificeFlow(OrificeFlow),
    CoulombFriction(CoulombFriction),
    GravityLoad(GravityLoad),
    Backlash(Backlash),
    Quantization(Quantization),
    LoadFlexibility(LoadFlexibility),
}

impl Effect {
    /// Builds an effect from its name and `key = value` pairs; keys not given
    /// take the catalog's defaults. Unknown names and keys are errors that
    /// list the valid ones.
    pub fn from_params(kind: EffectKind, given: &BTreeMap<String, f64>) -> Result<Self, PlantError> {
        let specs = kind.params();
        for key in given.keys() {
            if !specs.iter().any(|s| s.key == key) {
                return Err(PlantError::UnknownEffectKey {
                    effect: kind.name(),
                    key: key.clone(),
                    valid: if specs.is_empty() {
                        "(none: this effect has no parameters)".to_owned()
                    } else {
                        specs.iter().map(|s| s.key).collect::<Vec<_>>().join(", ")
                    },
                });
            }
        }
        let get = |key: &str| -> Result<f64, PlantError> {
            let spec = specs.iter().find(|s| s.key == key);
            let value = given.get(key).copied().or(spec.map(|s| s.default)).unwrap_or(f64::NAN);
            if !value.is_finite() {
                return Err(PlantError::InvalidEffectParam {
                    effect: kind.name(),
                    key: key.to_owned(),
                    value,
                    reason: "must be finite",
                });
            }
            Ok(value)
        };
        let positive = |key: &str| -> Result<f64, PlantError> {
            let value = get(key)?;
            if value <= 0.0 {
                return Err(PlantError::InvalidEffectParam {
                    effect: kind.name(),
                    key: key.to_owned(),
                    value,
                    reason: "must be positive",
                });
            }
            Ok(value)
        };
        let non_negative = |key: &str| -> Result<f64, PlantError> {
            let value = get(key)?;
            if value < 0.0 {
                return Err(PlantError::InvalidEffectParam {
                    effect: kind.name(),
                    key: key.to_owned(),
                    value,
                    reason: "must not be negative",
                });
            }
            Ok(value)
        };
        let effect = match kind {
            EffectKind::Deadzone => Effect::Deadzone(Deadzone {
                width: non_negative("width")?,
                offset: get("offset")?,
            }),
            EffectKind::Saturation => Effect::Saturation(Saturation {
                limit: positive("limit")?,
            }),
            EffectKind::TimeDelay => Effect::TimeDelay(TimeDelay {
                delay_s: non_negative("delay_s")?,
            }),
            EffectKind::AsymmetricGain => Effect::AsymmetricGain(AsymmetricGain {
                ratio: positive("ratio")?,
            }),
            EffectKind::OrificeFlow => Effect::OrificeFlow(OrificeFlow),
            EffectKind::CoulombFriction => {
                let coulomb = non_negative("coulomb")?;
                let breakaway = non_negative("breakaway")?;
                if breakaway < coulomb {
                    return Err(PlantError::InvalidEffectParam {
                        effect: kind.name(),
                        key: "breakaway".to_owned(),
                        value: breakaway,
                        reason: "must be at least coulomb",
                    });
                }
                Effect::CoulombFriction(CoulombFriction {
                    coulomb,
                    breakaway,
                    stribeck_velocity: positive("stribeck_velocity")?,
                })
            }
            EffectKind::GravityLoad => Effect::GravityLoad(GravityLoad {
                amplitude: get("amplitude")?,
                offset: get("offset")?,
            }),
            EffectKind::Backlash => Effect::Backlash(Backlash {
                width: non_negative("width")?,
            }),
            EffectKind::Quantization => Effect::Quantization(Quantization {
                step: positive("step")?,
            }),
            EffectKind::LoadFlexibility => {
                let load_fraction = positive("load_fraction")?;
                if load_fraction >= 1.0 {
                    return Err(PlantError::InvalidEffectParam {
                        effect: kind.name(),
                        key: "load_fraction".to_owned(),
                        value: load_fraction,
                        reason: "must be below 1",
                    });
                }
                Effect::LoadFlexibility(LoadFlexibility {
                    stiffness: positive("stiffness")?,
                    damping: non_negative("damping")?,
                    load_fraction,
                })
            }
        };
        Ok(effect)
    }

    /// Parses the command line's `NAME[:KEY=VALUE,KEY=VALUE]`.
    pub fn parse(spec: &str) -> Result<Self, PlantError> {
        let (name, rest) = match spec.split_once(':') {
            Some((name, rest)) => (name.trim(), rest),
            None => (spec.trim(), ""),
        };
        let kind = EffectKind::from_name(name)?;
        let mut given = BTreeMap::new();
        for pair in rest.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (key, value) = pair.split_once('=').ok_or_else(|| PlantError::MalformedEffect {
                spec: spec.to_owned(),
                reason: format!("`{pair}` is not KEY=VALUE"),
            })?;
            let value: f64 = value.trim().parse().map_err(|_| PlantError::MalformedEffect {
                spec: spec.to_owned(),
                reason: format!("`{}` is not a number", value.trim()),
            })?;
            given.insert(key.trim().to_owned(), value);
        }
        Self::from_params(kind, &given)
    }

    pub fn kind(&self) -> EffectKind {
        match self {
            Effect::Deadzone(_) => EffectKind::Deadzone,
            Effect::Saturation(_) => EffectKind::Saturation,
            Effect::TimeDelay(_) => EffectKind::TimeDelay,
            Effect::AsymmetricGain(_) => EffectKind::AsymmetricGain,
            Effect::OrificeFlow(_) => EffectKind::OrificeFlow,
            Effect::CoulombFriction(_) => EffectKind::CoulombFriction,
            Effect::GravityLoad(_) => EffectKind::GravityLoad,
            Effect::Backlash(_) => EffectKind::Backlash,
            Effect::Quantization(_) => EffectKind::Quantization,
            Effect::LoadFlexibility(_) => EffectKind::LoadFlexibility,
        }
    }

    /// The parameters as `(key, value)`, in the catalog's order.
    pub fn params(&self) -> Vec<(&'static str, f64)> {
        match *self {
            Effect::Deadzone(e) => vec![("width", e.width), ("offset", e.offset)],
            Effect::Saturation(e) => vec![("limit", e.limit)],
            Effect::TimeDelay(e) => vec![("delay_s", e.delay_s)],
            Effect::AsymmetricGain(e) => vec![("ratio", e.ratio)],
            Effect::OrificeFlow(_) => vec![],
            Effect::CoulombFriction(e) => vec![
                ("coulomb", e.coulomb),
                ("breakaway", e.breakaway),
                ("stribeck_velocity", e.stribeck_velocity),
            ],
            Effect::GravityLoad(e) => vec![("amplitude", e.amplitude), ("offset", e.offset)],
            Effect::Backlash(e) => vec![("width", e.width)],
            Effect::Quantization(e) => vec![("step", e.step)],
            Effect::LoadFlexibility(e) => vec![
                ("stiffness", e.stiffness),
                ("damping", e.damping),
                ("load_fraction", e.load_fraction),
            ],
        }
    }
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.kind().name())?;
        for (i, (key, value)) in self.params().iter().enumerate() {
            write!(f, "{}{key}={value}", if i == 0 { ':' } else { ',' })?;
        }
        Ok(())
    }
}

/// The effects switched on in a plant: at most one of each kind. Fixed
/// fields rather than a list, so the integrator's hot path branches on
/// `Option`s and never searches.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Effects {
    pub deadzone: Option<Deadzone>,
    pub saturation: Option<Saturation>,
    pub time_delay: Option<TimeDelay>,
    pub asymmetric_gain: Option<AsymmetricGain>,
    pub orifice_flow: Option<OrificeFlow>,
    pub coulomb_friction: Option<CoulombFriction>,
    pub gravity_load: Option<GravityLoad>,
    pub backlash: Option<Backlash>,
    pub quantization: Option<Quantization>,
    pub load_flexibility: Option<LoadFlexibility>,
}

impl Effects {
    pub fn none() -> Self {
        Self::default()
    }

    /// Where the valve's flow is affine by pieces of the spool: its dead
    /// band, of width 0 for an asymmetric gain alone (whose pieces are the
    /// spool's signs); `None` where one affine map holds for every spool.
    pub fn valve_band(&self) -> Option<Deadzone> {
        let piecewise = self.deadzone.is_some() || self.asymmetric_gain.is_some();
        piecewise.then(|| {
            self.deadzone.unwrap_or(Deadzone {
                width: 0.0,
                offset: 0.0,
            })
        })
    }

    /// Switches an effect on, replacing one of the same kind.
    pub fn insert(&mut self, effect: Effect) {
        match effect {
            Effect::Deadzone(e) => self.deadzone = Some(e),
            Effect::Saturation(e) => self.saturation = Some(e),
            Effect::TimeDelay(e) => self.time_delay = Some(e),
            Effect::AsymmetricGain(e) => self.asymmetric_gain = Some(e),
            Effect::OrificeFlow(e) => self.orifice_flow = Some(e),
            Effect::CoulombFriction(e) => self.coulomb_friction = Some(e),
            Effect::GravityLoad(e) => self.gravity_load = Some(e),
            Effect::Backlash(e) => self.backlash = Some(e),
            Effect::Quantization(e) => self.quantization = Some(e),
            Effect::LoadFlexibility(e) => self.load_flexibility = Some(e),
        }
    }

    pub fn list(&self) -> Vec<Effect> {
        let mut out = Vec::new();
        macro_rules! push {
            ($($field:ident => $variant:ident),*) => {
                $(if let Some(e) = self.$field { out.push(Effect::$variant(e)); })*
            };
        }
        push!(
            deadzone => Deadzone,
            saturation => Saturation,
            time_delay => TimeDelay,
            asymmetric_gain => AsymmetricGain,
            orifice_flow => OrificeFlow,
            coulomb_friction => CoulombFriction,
            gravity_load => GravityLoad,
            backlash => Backlash,
            quantization => Quantization,
            load_flexibility => LoadFlexibility
        );
        out
    }

    pub fn is_empty(&self) -> bool {
        self.list().is_empty()
    }
}

/// The TOML form of a set of effects: a table per switched-on effect, keyed
/// by name, e.g. `[effects.deadzone] width = 0.05`. An empty table switches
/// the effect on at its defaults.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct EffectsConfig(pub BTreeMap<String, BTreeMap<String, f64>>);

impl EffectsConfig {
    pub fn build(&self) -> Result<Effects, PlantError> {
        let mut effects = Effects::none();
        for (name, params) in &self.0 {
            effects.insert(Effect::from_params(EffectKind::from_name(name)?, params)?);
        }
        Ok(effects)
    }

    pub fn from_effects(effects: &Effects) -> Self {
        Self(
            effects
                .list()
                .iter()
                .map(|e| {
                    (
                        e.kind().name().to_owned(),
                        e.params().into_iter().map(|(k, v)| (k.to_owned(), v)).collect(),
                    )
                })
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantization_rounds_as_round_does_and_passes_nan_through() {
        let q = Quantization { step: 0.1745 };
        for i in -20_000..=20_000 {
            let angle = i as f64 * 0.000_731;
            let exact = (angle / q.step).round() * q.step;
            assert_eq!(q.quantize(angle), exact, "{angle}");
        }
        // Half a step rounds away from zero, as `round` does.
        assert_eq!(q.quantize(0.5 * q.step), q.step);
        assert_eq!(q.quantize(-0.5 * q.step), -q.step);
        assert!(q.quantize(f64::NAN).is_nan());
        assert_eq!(q.quantize(f64::INFINITY), f64::INFINITY);
        // Where adding a half would round, and around 2^52.
        let just_below_half = 0.5_f64.next_down();
        for counts in [
            just_below_half,
            -just_below_half,
            2.5,
            -3.5,
            1e15 + 0.5,
            4_503_599_627_370_495.5,
            4_503_599_627_370_497.0,
            1e300,
            -0.0,
        ] {
            assert_eq!(Quantization::nearest_count(counts), counts.round(), "{counts}");
        }
    }

    #[test]
    fn deadzone_removes_the_overlap() {
        let d = Deadzone {
            width: 0.1,
            offset: 0.0,
        };
        assert_eq!(d.opening(0.05), 0.0);
        assert_eq!(d.opening(-0.1), 0.0);
        assert!((d.opening(0.3) - 0.2).abs() < 1e-15);
        assert!((d.opening(-0.3) + 0.2).abs() < 1e-15);
        // A band off centre: a zero command opens it the other way.
        let off = Deadzone {
            width: 0.05,
            offset: 0.1,
        };
        assert_eq!(off.opening(0.12), 0.0);
        assert!((off.opening(0.0) + 0.05).abs() < 1e-15);
        assert!((off.opening(0.2) - 0.05).abs() < 1e-15);
    }

    #[test]
    fn saturation_clamps_travel() {
        let s = Saturation { limit: 0.5 };
        assert_eq!(s.clamp(0.7), 0.5);
        assert_eq!(s.clamp(-0.7), -0.5);
        assert_eq!(s.clamp(0.2), 0.2);
    }

    #[test]
    fn asymmetric_gain_scales_negative_side_only() {
        let a = AsymmetricGain { ratio: 0.7 };
        assert_eq!(a.gain_factor(0.3), 1.0);
        assert_eq!(a.gain_factor(-0.3), 0.7);
    }

    #[test]
    fn orifice_factor_is_a_root_and_one_at_nominal() {
        assert!((OrificeFlow::drop_factor(90e5, 90e5) - 1.0).abs() < 1e-12);
        assert!((OrificeFlow::drop_factor(22.5e5, 90e5) - 0.5).abs() < 1e-12);
        assert_eq!(OrificeFlow::drop_factor(-1e5, 90e5), 0.0);
        // Continuous at the laminar boundary.
        let edge = OrificeFlow::LAMINAR_FRACTION * 90e5;
        let below = OrificeFlow::drop_factor(edge * (1.0 - 1e-9), 90e5);
        let above = OrificeFlow::drop_factor(edge * (1.0 + 1e-9), 90e5);
        assert!((below - above).abs() < 1e-6);
    }

    #[test]
    fn stribeck_curve_falls_from_breakaway_to_coulomb() {
        let f = CoulombFriction {
            coulomb: 60.0,
            breakaway: 90.0,
            stribeck_velocity: 0.05,
        };
        assert!((f.sliding_level(0.0) - 90.0).abs() < 1e-12);
        assert!((f.sliding_level(0.05) - (60.0 + 30.0 / std::f64::consts::E)).abs() < 1e-9);
        assert!((f.sliding_level(1.0) - 60.0).abs() < 1e-9);
    }

    #[test]
    fn gravity_is_a_sine_of_the_offset_angle() {
        let g = GravityLoad {
            amplitude: 150.0,
            offset: 0.3,
        };
        assert!(g.torque(0.3).abs() < 1e-12);
        assert!((g.torque(0.3 + std::f64::consts::FRAC_PI_2) - 150.0).abs() < 1e-9);
    }

    #[test]
    fn backlash_follows_only_beyond_the_play() {
        let b = Backlash { width: 0.02 };
        assert_eq!(b.follow(0.005, 0.0), 0.0);
        assert!((b.follow(0.03, 0.0) - 0.02).abs() < 1e-15);
        assert!((b.follow(-0.03, 0.0) + 0.02).abs() < 1e-15);
        // Reversal: the follower stays until the play is crossed.
        assert!((b.follow(0.015, 0.02) - 0.02).abs() < 1e-15);
    }

    #[test]
    fn quantization_rounds_to_the_step() {
        let q = Quantization { step: 0.1 };
        assert!((q.quantize(0.26) - 0.3).abs() < 1e-12);
        assert!((q.quantize(-0.24) + 0.2).abs() < 1e-12);
    }

    #[test]
    fn flexibility_coupling_is_spring_plus_damper() {
        let f = LoadFlexibility {
            stiffness: 100.0,
            damping: 2.0,
            load_fraction: 0.5,
        };
        assert!((f.coupling_torque(0.1, 0.5) - 11.0).abs() < 1e-12);
    }

    #[test]
    fn every_catalog_name_round_trips_with_its_defaults() {
        for kind in EffectKind::ALL {
            let effect = Effect::parse(kind.name()).expect("defaults are valid");
            assert_eq!(effect.kind(), kind);
            let defaults: Vec<f64> = kind.params().iter().map(|p| p.default).collect();
            let values: Vec<f64> = effect.params().iter().map(|p| p.1).collect();
            assert_eq!(defaults, values, "{kind}");
            assert_eq!(Effect::parse(&effect.to_string()).expect("display parses"), effect);
        }
    }

    #[test]
    fn parse_reads_keys_and_rejects_unknown_ones_listing_the_valid() {
        let e = Effect::parse("deadzone:width=0.05").expect("valid");
        assert_eq!(
            e,
            Effect::Deadzone(Deadzone {
                width: 0.05,
                offset: 0.0
            })
        );
        let err = Effect::parse("deadzone:wdth=0.05").expect_err("unknown key");
        assert!(err.to_string().contains("width"), "{err}");
        let err = Effect::parse("dedzone").expect_err("unknown name");
        assert!(err.to_string().contains("coulomb_friction"), "{err}");
        assert!(Effect::parse("deadzone:width").is_err());
        assert!(Effect::parse("deadzone:width=abc").is_err());
        assert!(Effect::parse("saturation:limit=-1").is_err());
        assert!(Effect::parse("coulomb_friction:coulomb=100,breakaway=50").is_err());
    }

    #[test]
    fn config_round_trips_effects() {
        let mut effects = Effects::none();
        effects.insert(Effect::parse("backlash:width=0.01").expect("valid"));
        effects.insert(Effect::parse("gravity_load").expect("valid"));
        let config = EffectsConfig::from_effects(&effects);
        assert_eq!(config.build().expect("valid"), effects);
    }
}
