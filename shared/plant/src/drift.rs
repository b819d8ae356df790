//! A machine that changes while it runs: one effect's parameter moving
//! from one value to another over a stretch of time, as a valve's overlap
//! wears open or friction rises in the cold. For the machine stand-in, so
//! that the shadow model's drift detection meets a change it did not make.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::effects::{EffectKind, Effects};
use crate::PlantError;

/// `[machine.drift]`: `effect`'s `key` goes linearly from `from` to `to`
/// between `at_s` and `at_s + over_s` of the machine's time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriftSpec {
    pub effect: String,
    pub key: String,
    /// The value before the drift; the machine's own when it has the effect
    /// (then `from` must not be given), required when it has not (0 for a
    /// dead-zone's width: no dead-zone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from: Option<f64>,
    pub to: f64,
    pub at_s: f64,
    #[serde(default)]
    pub over_s: f64,
}

/// A drift made ready: every effect set along the way built at start-up,
/// so that the machine's loop only picks one.
#[derive(Debug, Clone)]
pub struct Drift {
    at_s: f64,
    over_s: f64,
    along: Vec<Effects>,
}

impl Drift {
    /// Steps along the way: a 0.06 dead-zone widens in steps of 0.0006.
    pub const STEPS: usize = 100;

    pub fn new(base: &Effects, spec: &DriftSpec) -> Result<Self, PlantError> {
        let kind = EffectKind::from_name(&spec.effect)?;
        let invalid = |key: &str, value: f64, reason: &'static str| PlantError::InvalidEffectParam {
            effect: kind.name(),
            key: key.to_owned(),
            value,
            reason,
        };
        if matches!(kind, EffectKind::TimeDelay | EffectKind::LoadFlexibility) {
            // A delay line's length and a flexible load's states are the
            // plant's structure, made once.
            return Err(invalid(
                &spec.key,
                spec.to,
                "cannot drift: it changes the plant's structure",
            ));
        }
        if !(spec.at_s.is_finite() && spec.at_s >= 0.0) {
            return Err(invalid("at_s", spec.at_s, "the drift's start must be a time ≥ 0"));
        }
        if !(spec.over_s.is_finite() && spec.over_s >= 0.0) {
            return Err(invalid("over_s", spec.over_s, "the drift's duration must be ≥ 0"));
        }
        let present = base.list().into_iter().find(|e| e.kind() == kind);
        let mut params: BTreeMap<String, f64> = present
            .map(|e| e.params().into_iter().map(|(k, v)| (k.to_owned(), v)).collect())
            .unwrap_or_default();
        let from = match (present, spec.from) {
            (Some(_), Some(from)) => {
                return Err(invalid(
                    "from",
                    from,
                    "the machine has this effect: the drift starts from its value",
                ))
            }
            (Some(_), None) => *params
                .get(&spec.key)
                .ok_or_else(|| invalid(&spec.key, spec.to, "not a parameter of this effect"))?,
            (None, Some(from)) => from,
            (None, None) => {
                return Err(invalid(
                    "from",
                    f64::NAN,
                    "the machine lacks this effect: give its value before the drift",
                ))
            }
        };
        let mut along = Vec::with_capacity(Self::STEPS + 1);
        for step in 0..=Self::STEPS {
            params.insert(
                spec.key.clone(),
                from + (spec.to - from) * step as f64 / Self::STEPS as f64,
            );
            let mut effects = *base;
            effects.insert(crate::Effect::from_params(kind, &params)?);
            along.push(effects);
        }
        Ok(Self {
            at_s: spec.at_s,
            over_s: spec.over_s,
            along,
        })
    }

    /// The machine's effects at `t` seconds of its time.
    pub fn effects_at(&self, t: f64) -> &Effects {
        let progress = if self.over_s > 0.0 {
            ((t - self.at_s) / self.over_s).clamp(0.0, 1.0)
        } else if t >= self.at_s {
            1.0
        } else {
            0.0
        };
        &self.along[(progress * Self::STEPS as f64).round() as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(text: &str) -> DriftSpec {
        toml::from_str(text).expect("a drift")
    }

    #[test]
    fn a_deadzone_widens_from_none_to_its_new_width_over_the_given_time() {
        let drift = Drift::new(
            &Effects::none(),
            &spec("effect = 'deadzone'\nkey = 'width'\nfrom = 0.0\nto = 0.06\nat_s = 10\nover_s = 2"),
        )
        .expect("valid");
        let width = |t: f64| drift.effects_at(t).deadzone.map_or(f64::NAN, |d| d.width);
        assert_eq!(width(0.0), 0.0);
        assert_eq!(width(10.0), 0.0);
        assert!((width(11.0) - 0.03).abs() < 1e-12);
        assert!((width(12.0) - 0.06).abs() < 1e-12);
        assert!((width(100.0) - 0.06).abs() < 1e-12);
    }

    #[test]
    fn a_drift_starts_from_the_machines_own_value_and_keeps_its_other_effects() {
        let mut base = Effects::none();
        base.insert(crate::Effect::parse("coulomb_friction:coulomb=40,breakaway=60").expect("effect"));
        base.insert(crate::Effect::parse("gravity_load:amplitude=100").expect("effect"));
        let drift = Drift::new(
            &base,
            &spec("effect = 'coulomb_friction'\nkey = 'coulomb'\nto = 55\nat_s = 1"),
        )
        .expect("valid");
        assert_eq!(drift.effects_at(0.5).coulomb_friction.map(|c| c.coulomb), Some(40.0));
        assert_eq!(drift.effects_at(1.0).coulomb_friction.map(|c| c.coulomb), Some(55.0));
        assert_eq!(drift.effects_at(1.0).gravity_load, base.gravity_load);
    }

    #[test]
    fn what_cannot_drift_is_refused_with_its_reason() {
        let base = Effects::none();
        let err = |text: &str| Drift::new(&base, &spec(text)).expect_err("refused").to_string();
        assert!(err("effect = 'time_delay'\nkey = 'delay_s'\nfrom = 0\nto = 0.01\nat_s = 1").contains("structure"));
        assert!(err("effect = 'deadzone'\nkey = 'width'\nto = 0.06\nat_s = 1").contains("give its value"));
        assert!(err("effect = 'deadzone'\nkey = 'widht'\nfrom = 0\nto = 0.06\nat_s = 1").contains("widht"));
        assert!(err("effect = 'deadzone'\nkey = 'width'\nfrom = 0\nto = -0.06\nat_s = 1").contains("negative"));
        assert!(err("effect = 'deadzone'\nkey = 'width'\nfrom = 0\nto = 0.06\nat_s = -1").contains("at_s"));
    }
}
