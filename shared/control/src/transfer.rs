//! Bumpless transfer into a controller whose state is not forced to the
//! running output: the difference is carried beside it and fades.

/// The running controller's output less this controller's own, added to
/// its output and faded out after the switch. Its controller's state runs
/// on untouched, as it would in charge.
#[derive(Debug, Clone, Copy)]
pub struct FadingTransfer {
    offset: f64,
    fade: f64,
    /// The controller's own last output, before the offset.
    own: f64,
}

impl FadingTransfer {
    /// An offset that falls to 1/e in `fade_s`, at sample time `ts`.
    pub fn new(fade_s: f64, ts: f64) -> Self {
        Self {
            offset: 0.0,
            fade: (-ts / fade_s).exp(),
            own: 0.0,
        }
    }

    pub fn reset(&mut self) {
        self.offset = 0.0;
        self.own = 0.0;
    }

    /// This period's output: the controller's `own` and what is left of the
    /// offset, which then fades by a period.
    pub fn apply(&mut self, own: f64) -> f64 {
        self.own = own;
        let output = own + self.offset;
        self.offset *= self.fade;
        output
    }

    /// While standing by: after this period's [`FadingTransfer::apply`],
    /// the offset that makes the output the running one's. A non-finite
    /// one is no output to take over, and a NaN offset would never fade.
    pub fn track(&mut self, running: f64) {
        let offset = running - self.own;
        if offset.is_finite() {
            self.offset = offset;
        }
    }

    /// A start from a running loop: the next output is `output` where the
    /// controller's own is expected to be `own`.
    pub fn start(&mut self, output: f64, own: f64) {
        self.own = own;
        self.offset = output - own;
    }
}

#[cfg(test)]
mod tests {
    use super::FadingTransfer;

    #[test]
    fn a_tracked_step_is_bumpless_then_fades_to_nothing() {
        let mut transfer = FadingTransfer::new(0.05, 0.001);
        assert_eq!(transfer.apply(0.2), 0.2);
        transfer.track(0.5);
        assert!((transfer.apply(0.2) - 0.5).abs() < 1e-12, "bumpless");
        let mut last = 0.0;
        for _ in 0..49 {
            last = transfer.apply(0.2);
        }
        // 49 periods of 1 ms after the first: e^(−49/50) of the step left.
        assert!((last - 0.2 - 0.3 * (-0.98f64).exp()).abs() < 1e-12, "{last}");
        for _ in 0..450 {
            last = transfer.apply(0.2);
        }
        assert!((last - 0.2).abs() < 0.3 * (-9.9f64).exp(), "{last}");
        transfer.track(f64::NAN);
        assert!(transfer.apply(0.2).is_finite(), "a NaN taken over would never fade");
    }
}
