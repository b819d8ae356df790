//! What the loop last measured of the plant, value by value: where a
//! simulated plant takes over from the machine, or a restarted plant
//! resumes. On CAN a node that stops answering leaves its values NaN (the
//! reading invalid); a simulated plant started from them would integrate
//! NaN to the end of the run, so each value is the newest finite one.

use hydractl_plant::PlantState;
use hydractl_samples::PlantReading;

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct LastMeasured {
    angle: Option<f64>,
    p_a: Option<f64>,
    p_b: Option<f64>,
    /// The sensor stage's estimate, rad/s.
    velocity: Option<f64>,
}

impl LastMeasured {
    pub(crate) fn reading(&mut self, r: &PlantReading) {
        keep_finite(&mut self.angle, r.angle);
        keep_finite(&mut self.p_a, r.p_a);
        keep_finite(&mut self.p_b, r.p_b);
    }

    pub(crate) fn velocity(&mut self, velocity: f64) {
        keep_finite(&mut self.velocity, velocity);
    }

    /// A restarted plant's `--resume`.
    pub(crate) fn of_resume(resume: &crate::Resume) -> Self {
        let mut measured = Self::default();
        keep_finite(&mut measured.angle, resume.angle);
        keep_finite(&mut measured.p_a, resume.p_a);
        keep_finite(&mut measured.p_b, resume.p_b);
        keep_finite(&mut measured.velocity, resume.velocity);
        measured
    }

    /// The angle to home the sensors on, when one was measured.
    pub(crate) fn angle(&self) -> Option<f64> {
        self.angle
    }

    /// `state` with what was measured put in; what never was keeps the
    /// plant's own value, a velocity never estimated is rest.
    pub(crate) fn put_into(&self, state: &mut PlantState) {
        if let Some(angle) = self.angle {
            (state.angle, state.load_angle) = (angle, angle);
        }
        state.p_a = self.p_a.unwrap_or(state.p_a);
        state.p_b = self.p_b.unwrap_or(state.p_b);
        let velocity = self.velocity.unwrap_or(0.0);
        (state.velocity, state.load_velocity) = (velocity, velocity);
    }
}

fn keep_finite(slot: &mut Option<f64>, value: f64) {
    if value.is_finite() {
        *slot = Some(value);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plant_state(angle: f64, p_a: f64, velocity: f64) -> PlantState {
        PlantState {
            spool: 0.0,
            spool_rate: 0.0,
            p_a,
            p_b: 1.0,
            angle,
            velocity,
            load_angle: angle,
            load_velocity: velocity,
            stuck: false,
        }
    }

    #[test]
    fn a_lost_sensors_nan_keeps_its_last_value_and_never_reaches_the_state() {
        let mut measured = LastMeasured::default();
        let reading = |angle, p_a| PlantReading {
            angle,
            p_a,
            p_b: 4e6,
            ..PlantReading::default()
        };
        measured.reading(&reading(0.3, 7e6));
        measured.velocity(0.5);
        // The encoder's node stopped: NaN angle, the pressures still come.
        measured.reading(&reading(f64::NAN, 8e6));
        measured.velocity(f64::NAN);
        let mut state = plant_state(1.0, 1.0, 1.0);
        measured.put_into(&mut state);
        assert_eq!((state.angle, state.load_angle), (0.3, 0.3));
        assert_eq!((state.p_a, state.p_b), (8e6, 4e6));
        assert_eq!((state.velocity, state.load_velocity), (0.5, 0.5));
        // Nothing measured: the plant's own state, at rest.
        let mut own = plant_state(1.0, 2.0, 3.0);
        LastMeasured::default().put_into(&mut own);
        assert_eq!((own.angle, own.p_a, own.velocity), (1.0, 2.0, 0.0));
    }
}
