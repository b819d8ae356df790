//! Plant readings joined with the valve command that answered each, by the
//! reading's sequence number: the one join behind the model tools' rows,
//! live (the shadow) and from a recording (`export-csv`).

use std::collections::BTreeMap;

use hydractl_samples::{PlantReading, ValveSample};

/// Readings waiting for their valve sample, and the sample whose command
/// the valve holds.
#[derive(Debug, Default)]
pub struct CommandJoin {
    pending: BTreeMap<u64, PlantReading>,
    held: Option<ValveSample>,
}

impl CommandJoin {
    pub fn new() -> Self {
        Self::default()
    }

    /// A reading, kept until a valve sample of its sequence number or a
    /// later one arrives.
    pub fn reading(&mut self, reading: PlantReading) {
        self.pending.insert(reading.sensor_seq, reading);
    }

    /// A valve sample: its reading, and every earlier one still waiting,
    /// oldest first, go to `row` with the valve sample in effect at it and
    /// whether that sample is the reading's own. A reading whose command
    /// never came gets the one before (as the valve holds its current), or
    /// none before the first.
    pub fn valve(&mut self, valve: ValveSample, mut row: impl FnMut(&PlantReading, Option<&ValveSample>, bool)) {
        while let Some(entry) = self.pending.first_entry().filter(|e| *e.key() <= valve.sensor_seq) {
            let (seq, reading) = entry.remove_entry();
            let own = seq == valve.sensor_seq;
            if own {
                self.held = Some(valve);
            }
            row(&reading, self.held.as_ref(), own);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(seq: u64) -> PlantReading {
        PlantReading {
            sensor_seq: seq,
            ..Default::default()
        }
    }

    fn valve(seq: u64, command: f64) -> ValveSample {
        ValveSample {
            sensor_seq: seq,
            command,
            ..Default::default()
        }
    }

    #[test]
    fn a_reading_gets_its_own_command_or_holds_the_one_before() {
        let mut join = CommandJoin::new();
        let mut rows = Vec::new();
        let feed = |join: &mut CommandJoin, v: ValveSample| {
            let mut joined = Vec::new();
            join.valve(v, |r, v, own| joined.push((r.sensor_seq, v.map(|v| v.command), own)));
            joined
        };
        join.reading(reading(1));
        rows.extend(feed(&mut join, valve(1, 0.1)));
        join.reading(reading(2));
        join.reading(reading(3));
        join.reading(reading(4));
        rows.extend(feed(&mut join, valve(3, 0.3)));
        rows.extend(feed(&mut join, valve(3, 0.0)));
        assert_eq!(
            rows,
            vec![(1, Some(0.1), true), (2, Some(0.1), false), (3, Some(0.3), true)]
        );
        assert_eq!(feed(&mut join, valve(4, 0.4)), vec![(4, Some(0.4), true)]);
    }

    #[test]
    fn a_reading_before_the_first_command_holds_none() {
        let mut join = CommandJoin::new();
        let mut rows = Vec::new();
        join.reading(reading(7));
        join.reading(reading(8));
        join.valve(valve(8, 0.5), |r, v, own| {
            rows.push((r.sensor_seq, v.map(|v| v.command), own))
        });
        assert_eq!(rows, vec![(7, None, false), (8, Some(0.5), true)]);
    }
}
