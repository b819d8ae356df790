//! The shadow process's logic: the loop's readings and valve commands
//! joined into the model tools' rows, the model compared over the last
//! window, and a drift named by a diagnosis in a thread of its own.

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::thread::JoinHandle;

use anyhow::{Context, Result};
use hydractl_config::ShadowConfig;
use hydractl_ident::greybox::{
    diagnose, moved_effect, Assessment, Diagnosis, DriftAlarm, DriftTest, FitOptions, Model, ModelError, Part, Shadow,
    Signals, REGIMES,
};
use hydractl_ident::Dataset;
use hydractl_plant::EffectKind;
use hydractl_plant::PA_PER_BAR;
use hydractl_recording::CommandJoin;
use hydractl_samples::{drift, fixed_name, ModelDrift, PlantReading, ShadowSample, ValveSample};

/// One control period as the model reads it: `t, u, p_a (bar), p_b, theta`.
type Row = [f64; 5];

/// Readings joined with the valve command computed from them
/// ([`CommandJoin`], as `mcap export-csv` joins them); a run of consecutive readings
/// from one source (a gap or a handover starts it afresh).
pub struct Rows {
    period_s: f64,
    /// The [`hydractl_samples::source`] whose readings the rows take: the model describes
    /// the machine, not the simulation that stands in when it is lost.
    watched: u32,
    capacity: usize,
    rows: VecDeque<Row>,
    /// The sequence number and source of the newest row.
    last: Option<(u64, u32)>,
    join: CommandJoin,
    /// Rows accepted since the start, and that count when the current run
    /// of rows began: marks taken from it never run backwards over a gap.
    accepted: u64,
    run_start: u64,
    gaps: u64,
}

impl Rows {
    pub fn new(period_s: f64, capacity: usize, watched: u32) -> Self {
        Self {
            period_s,
            watched,
            capacity,
            rows: VecDeque::with_capacity(capacity),
            last: None,
            join: CommandJoin::new(),
            accepted: 0,
            run_start: 0,
            gaps: 0,
        }
    }

    /// A reading; one from another source than the watched is left out,
    /// and the rows start afresh when the watched one comes back.
    pub fn reading(&mut self, reading: PlantReading) {
        if reading.source == self.watched {
            self.join.reading(reading);
        }
    }

    /// A valve sample: its reading becomes a row, and any reading before it
    /// whose command never came holds the command before (as the valve does).
    pub fn valve(&mut self, valve: ValveSample) {
        let mut join = std::mem::take(&mut self.join);
        join.valve(valve, |reading, valve, _| {
            self.push(reading, valve.map_or(0.0, |v| v.command))
        });
        self.join = join;
    }

    fn push(&mut self, r: &PlantReading, command: f64) {
        let continues = self
            .last
            .is_some_and(|(seq, source)| r.sensor_seq == seq + 1 && r.source == source);
        if !continues {
            if self.last.is_some() {
                self.gaps += 1;
            }
            self.rows.clear();
            self.run_start = self.accepted;
        }
        if self.rows.len() == self.capacity {
            self.rows.pop_front();
        }
        let row = [
            r.sensor_seq as f64 * self.period_s,
            command,
            r.p_a / PA_PER_BAR,
            r.p_b / PA_PER_BAR,
            r.angle,
        ];
        if row.iter().all(|v| v.is_finite()) {
            self.rows.push_back(row);
            self.accepted += 1;
            self.last = Some((r.sensor_seq, r.source));
        } else {
            // A reading the sensors flagged: the window starts after it.
            self.rows.clear();
            self.run_start = self.accepted;
            self.last = None;
            self.gaps += 1;
        }
    }

    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Times the rows started afresh.
    pub fn gaps(&self) -> u64 {
        self.gaps
    }

    /// A mark of now, for [`Rows::since`].
    pub(crate) fn mark(&self) -> u64 {
        self.accepted
    }

    /// Rows of the current run accepted after `mark`: a gap since then
    /// leaves only the rows after it.
    pub fn since(&self, mark: u64) -> u64 {
        self.accepted - mark.max(self.run_start)
    }

    /// The time of the newest row, s on the loop's clock.
    pub(crate) fn newest_t(&self) -> Option<f64> {
        self.rows.back().map(|r| r[0])
    }

    /// The last `n` rows: `t, u, p_a (bar), p_b, theta`.
    pub fn last(&self, n: usize) -> impl Iterator<Item = &[f64; 5]> {
        self.rows.iter().skip(self.rows.len().saturating_sub(n))
    }

    /// The last `n` rows as the model tools' signals.
    pub fn signals(&self, n: usize) -> Result<Signals, ModelError> {
        let mut columns: [Vec<f64>; 5] = Default::default();
        for row in self.last(n) {
            for (column, value) in columns.iter_mut().zip(row) {
                column.push(*value);
            }
        }
        let [t, u, p_a, p_b, theta] = columns;
        let data = Dataset::from_columns(
            "the live samples",
            vec![("t", t), ("u", u), ("p_a", p_a), ("p_b", p_b), ("theta", theta)],
        );
        Signals::from_dataset(&data)
    }
}

/// Where the shadow is with a drift.
enum DriftState {
    Watching,
    /// An alarm: collecting data from after it for the diagnosis.
    Collecting {
        alarm: ModelDrift,
        /// [`Rows::mark`] at the alarm, or at the end of the first window.
        mark: u64,
        attempt: u8,
    },
    Diagnosing {
        alarm: ModelDrift,
        worker: JoinHandle<Result<Diagnosis, ModelError>>,
        /// [`Rows::mark`] at the end of the window diagnosed.
        window_end: u64,
        attempt: u8,
    },
}

/// What the shadow has to publish after a step.
#[derive(Default)]
pub struct Outputs {
    pub sample: Option<ShadowSample>,
    pub drift: Vec<ModelDrift>,
}

/// The shadow: the model, its rows and its drift test.
pub struct ShadowWatch {
    shadow: Shadow,
    rows: Rows,
    window: usize,
    every: u64,
    new_segments: usize,
    diagnose_rows: u64,
    window_s: f64,
    assessed_at: u64,
    alarms: u32,
    state: DriftState,
    /// `[shadow] learned`: where an adopted model is written.
    learned: Option<std::path::PathBuf>,
}

impl ShadowWatch {
    /// The shadow of the [`hydractl_samples::source`] `watched`: the machine where the
    /// config has one, else the simulated plant.
    pub fn open(config: &ShadowConfig, period_s: f64, watched: u32) -> Result<Self> {
        let path = config
            .model
            .as_deref()
            .context("the config's [shadow] names no model")?;
        Self::with_model(load(path)?, config, period_s, watched)
    }

    pub fn with_model(model: Model, config: &ShadowConfig, period_s: f64, watched: u32) -> Result<Self> {
        let rows_of = |s: f64| (s / period_s).round() as usize;
        let window = rows_of(config.window_s);
        let diagnose_rows = rows_of(config.diagnose_s);
        Ok(Self {
            shadow: Shadow::new(model, DriftTest::default())?,
            rows: Rows::new(period_s, window.max(diagnose_rows), watched),
            window,
            every: rows_of(config.every_s) as u64,
            new_segments: (config.every_s / hydractl_ident::greybox::SEGMENT_S).round() as usize,
            diagnose_rows: diagnose_rows as u64,
            window_s: config.window_s,
            assessed_at: 0,
            alarms: 0,
            state: DriftState::Watching,
            learned: config.learned.clone(),
        })
    }

    pub fn rows(&mut self) -> &mut Rows {
        &mut self.rows
    }

    /// After new rows: a window's comparison when one is due, a drift's
    /// alarm, its diagnosis started once enough data followed it, and its
    /// outcome when the diagnosis is done.
    pub fn step(&mut self, last: Option<&PlantReading>, now_ns: u64) -> Result<Outputs> {
        let mut out = Outputs::default();
        if let Some(done) = self.poll_diagnosis()? {
            out.drift.push(done);
        }
        let Some(last) = last else { return Ok(out) };
        if self.rows.len() < self.window || self.rows.since(self.assessed_at) < self.every {
            return Ok(out);
        }
        self.assessed_at = self.rows.mark();
        let signals = self.rows.signals(self.window)?;
        let assessment = self.shadow.assess(&signals, self.new_segments);
        let t = self.rows.newest_t().unwrap_or(0.0);
        match &self.state {
            DriftState::Watching => {
                if let Some(alarm) = assessment.alarms.iter().max_by(|a, b| a.size.total_cmp(&b.size)) {
                    self.alarms += 1;
                    let event = detected(alarm, last, t, now_ns);
                    out.drift.push(event);
                    self.state = DriftState::Collecting {
                        alarm: event,
                        mark: self.rows.mark(),
                        attempt: 0,
                    };
                }
            }
            DriftState::Collecting { alarm, mark, attempt } => {
                // Only consecutive rows after the alarm: a gap in them
                // (a reader starved past its buffer) starts the count again.
                if self.rows.since(*mark) >= self.diagnose_rows {
                    let signals = self.rows.signals(self.diagnose_rows as usize)?;
                    let model = self.shadow.model().clone();
                    let (alarm, attempt) = (*alarm, *attempt);
                    let worker = std::thread::Builder::new()
                        .name("diagnose".into())
                        .spawn(move || {
                            // One thread: the shadow must not take the
                            // computer's other CPUs from the loop's peers.
                            let pool = rayon::ThreadPoolBuilder::new()
                                .num_threads(1)
                                .build()
                                .map_err(|e| ModelError::Fit(e.to_string()))?;
                            pool.install(|| diagnose(&signals, Some(&model), FitOptions::default()))
                        })
                        .context("starting the diagnosis")?;
                    self.state = DriftState::Diagnosing {
                        alarm,
                        worker,
                        window_end: self.rows.mark(),
                        attempt,
                    };
                }
            }
            DriftState::Diagnosing { .. } => {}
        }
        out.sample = Some(self.sample(&assessment, last, now_ns));
        Ok(out)
    }

    fn poll_diagnosis(&mut self) -> Result<Option<ModelDrift>> {
        if !matches!(&self.state, DriftState::Diagnosing { worker, .. } if worker.is_finished()) {
            return Ok(None);
        }
        let DriftState::Diagnosing {
            alarm,
            worker,
            window_end,
            attempt,
        } = std::mem::replace(&mut self.state, DriftState::Watching)
        else {
            return Ok(None);
        };
        let diagnosis = worker
            .join()
            .map_err(|_| anyhow::anyhow!("the diagnosis thread panicked"))?;
        let mut event = alarm;
        event.stage = drift::UNNAMED;
        event.params = [f64::NAN; 4];
        match diagnosis {
            Ok(diagnosis) => {
                // An effect the model lacks, else one it has whose size moved.
                let named = match diagnosis.candidates.first().filter(|c| c.significant) {
                    Some(c) => Some((
                        c.effect.clone(),
                        c.params.clone(),
                        diagnosis.fitted.get(&c.effect).cloned(),
                        c.evidence.clone(),
                    )),
                    None => moved_effect(self.shadow.model(), &diagnosis).map(|(effect, params)| {
                        let evidence = format!(
                            "the model's own {effect} refitted on the drifted data moved beyond a quarter \
                             and three standard deviations"
                        );
                        (effect, params, Some(diagnosis.baseline_model.clone()), evidence)
                    }),
                };
                match named {
                    Some((effect, params, model, evidence)) => {
                        event.stage = drift::NAMED;
                        event.effect = fixed_name(&effect);
                        let keys = EffectKind::from_name(&effect)
                            .map(|k| k.params().iter().map(|p| p.key).collect::<Vec<_>>())
                            .unwrap_or_default();
                        for (slot, key) in event.params.iter_mut().zip(keys) {
                            *slot = params.get(key).copied().unwrap_or(f64::NAN);
                        }
                        tracing::warn!(effect = %effect, params = ?params, evidence = %evidence, "the machine drifted: named");
                        match model {
                            Some(model) => {
                                if let Some(path) = &self.learned {
                                    // Off the loop: the shadow's own thread.
                                    match model.save(path) {
                                        Ok(()) => {
                                            tracing::info!(file = %path.display(), "the learned model is written")
                                        }
                                        Err(e) => tracing::warn!("the learned model is not written: {e}"),
                                    }
                                }
                                self.shadow.adopt(model)?;
                            }
                            None => self.shadow.restart(),
                        }
                    }
                    None if attempt == 0 => {
                        // An alarm raised while the machine changes sees
                        // the change inside its first window, and an effect
                        // fitted as one size across it may explain too
                        // little: the next window holds the machine as it
                        // now is.
                        tracing::info!(
                            verdict = %diagnosis.verdict,
                            "the drift's first window names no effect: once more on the next"
                        );
                        self.state = DriftState::Collecting {
                            alarm,
                            mark: window_end,
                            attempt: 1,
                        };
                        return Ok(None);
                    }
                    None => {
                        tracing::warn!(verdict = %diagnosis.verdict, "the machine drifted: no effect of the catalog names it");
                        self.shadow.restart();
                    }
                }
            }
            Err(e) => {
                tracing::warn!("the machine drifted; its diagnosis failed: {e}");
                self.shadow.restart();
            }
        }
        event.stage_time_ns = hydractl_bus::clock::now_ns();
        Ok(Some(event))
    }

    fn sample(&self, a: &Assessment, last: &PlantReading, now_ns: u64) -> ShadowSample {
        let fit = |output: &str| {
            a.comparison
                .outputs
                .iter()
                .find(|o| o.output == output)
                .map_or(f64::NAN, |o| o.fit_percent)
        };
        let angle_part = [Part::Mechanical, Part::Whole]
            .into_iter()
            .find(|p| a.residual_rms.contains_key(p))
            .unwrap_or(Part::Mechanical);
        let of = |map: &BTreeMap<Part, f64>, part: Part| map.get(&part).copied().unwrap_or(f64::NAN);
        let mut regime_pressures = [f64::NAN; 8];
        let mut regime_angle = [f64::NAN; 8];
        for score in &a.comparison.regimes {
            let Some(i) = REGIMES.iter().position(|r| *r == score.regime) else {
                continue;
            };
            let pressures = ["p_a", "p_b"]
                .iter()
                .filter_map(|o| score.nrmse.get(*o))
                .map(|v| v * v)
                .collect::<Vec<_>>();
            if !pressures.is_empty() {
                regime_pressures[i] = (pressures.iter().sum::<f64>() / pressures.len() as f64).sqrt();
            }
            regime_angle[i] = score.nrmse.get("theta").copied().unwrap_or(f64::NAN);
        }
        ShadowSample {
            seq: 0,
            sensor_seq: last.sensor_seq,
            sensor_time_ns: last.sensor_time_ns,
            stage_time_ns: now_ns,
            window_s: self.window_s,
            fit_theta: fit("theta"),
            fit_p_a: fit("p_a"),
            fit_p_b: fit("p_b"),
            residual_pressures: of(&a.residual_rms, Part::Hydraulic),
            residual_angle: of(&a.residual_rms, angle_part),
            normalized_pressures: of(&a.normalized, Part::Hydraulic),
            normalized_angle: of(&a.normalized, angle_part),
            cusum_pressures: of(&a.cusum, Part::Hydraulic),
            cusum_angle: of(&a.cusum, angle_part),
            cusum_threshold: self.shadow.test().threshold,
            regime_pressures,
            regime_angle,
            row_gaps: self.rows.gaps(),
            drift_alarms: self.alarms,
            diagnosing: u32::from(!matches!(self.state, DriftState::Watching)),
        }
    }
}

fn load(path: &Path) -> Result<Model> {
    Model::load(path).with_context(|| format!("the shadow's model {}", path.display()))
}

fn detected(alarm: &DriftAlarm, last: &PlantReading, t: f64, now_ns: u64) -> ModelDrift {
    tracing::warn!(
        part = alarm.part.name(),
        regime = %alarm.regime,
        size = alarm.size,
        rms_ratio = alarm.rms_ratio,
        at_s = t,
        "the machine drifts from its model"
    );
    ModelDrift {
        seq: 0,
        sensor_seq: last.sensor_seq,
        sensor_time_ns: last.sensor_time_ns,
        stage_time_ns: now_ns,
        detected_after_s: t,
        size: alarm.size,
        rms_ratio: alarm.rms_ratio,
        params: [f64::NAN; 4],
        stage: drift::DETECTED,
        reserved: 0,
        part: fixed_name(alarm.part.name()),
        regime: fixed_name(&alarm.regime),
        effect: [0; 24],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(seq: u64, source: u32) -> PlantReading {
        PlantReading {
            sensor_seq: seq,
            angle: seq as f64 * 1e-3,
            p_a: 50e5,
            p_b: 40e5,
            source,
            ..PlantReading::default()
        }
    }

    fn valve(seq: u64, command: f64) -> ValveSample {
        ValveSample {
            sensor_seq: seq,
            command,
            ..ValveSample::default()
        }
    }

    #[test]
    fn a_reading_becomes_a_row_with_its_own_command_or_the_one_before() {
        let mut rows = Rows::new(1e-3, 10, 0);
        for seq in 0..3 {
            rows.reading(reading(seq, 0));
        }
        rows.valve(valve(0, 0.1));
        // The command for reading 1 never came: 2's releases both.
        rows.valve(valve(2, 0.3));
        let u: Vec<f64> = rows.last(10).map(|r| r[1]).collect();
        assert_eq!(u, vec![0.1, 0.1, 0.3]);
        let p_a = rows.last(1).next().map_or(f64::NAN, |r| r[2]);
        assert!((p_a - 50.0).abs() < 1e-9, "Pa on the bus, bar in the rows: {p_a}");
        assert_eq!(rows.newest_t(), Some(2e-3));
    }

    #[test]
    fn a_gap_the_other_plant_or_a_flagged_reading_starts_the_window_afresh() {
        let mut rows = Rows::new(1e-3, 10, 0);
        let feed = |rows: &mut Rows, r: PlantReading| {
            let seq = r.sensor_seq;
            rows.reading(r);
            rows.valve(valve(seq, 0.0));
        };
        for seq in 0..4 {
            feed(&mut rows, reading(seq, 0));
        }
        assert_eq!(rows.len(), 4);
        feed(&mut rows, reading(6, 0));
        assert_eq!(rows.len(), 1, "a gap");
        feed(&mut rows, reading(7, 1));
        assert_eq!(rows.len(), 1, "the other plant's reading is not the watched one's");
        feed(&mut rows, reading(8, 0));
        assert_eq!(rows.len(), 1, "back from the other plant");
        feed(
            &mut rows,
            PlantReading {
                angle: f64::NAN,
                ..reading(9, 0)
            },
        );
        assert!(rows.is_empty(), "a reading without its angle");
        assert_eq!(rows.gaps(), 3);
        for seq in 10..31 {
            feed(&mut rows, reading(seq, 0));
        }
        assert_eq!(rows.len(), 10, "at most its capacity");
        assert_eq!(rows.since(0), 21);
    }

    #[test]
    fn rows_since_a_mark_count_only_the_run_after_the_last_gap() {
        let mut rows = Rows::new(1e-3, 100, 0);
        let feed = |rows: &mut Rows, seq: u64| {
            rows.reading(reading(seq, 0));
            rows.valve(valve(seq, 0.0));
        };
        (0..10).for_each(|seq| feed(&mut rows, seq));
        let mark = rows.mark();
        (10..15).for_each(|seq| feed(&mut rows, seq));
        assert_eq!(rows.since(mark), 5);
        (20..23).for_each(|seq| feed(&mut rows, seq));
        assert_eq!(rows.since(mark), 3, "the gap at 15..20 left three rows after it");
        assert_eq!(rows.since(rows.mark()), 0);
    }
}
