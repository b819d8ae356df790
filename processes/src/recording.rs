//! Between the bus and MCAP: taps that drain a service into a recording
//! (the recorder), and outlets that put recorded samples back on their
//! services (replay). A service's payload type, read from its iceoryx2
//! config or from the recording's schema, picks the Rust type through
//! `hydractl_samples::visit_kind`.

use std::collections::BTreeSet;

use anyhow::{Context, Result};
use hydractl_bus::{Bus, Outlet, Reader};
use hydractl_recording::{encode_frame, ChannelHandle, RecordingWriter, CAN_FRAME_KIND};
use hydractl_samples::{visit_kind, CanFrameSample, KindVisitor, Recordable, RecorderStatus, STACK_SERVICES};

/// Samples a tap keeps for the recorder between two drains: 256 ms of a
/// 1 kHz loop, far more than the recorder's 5 ms tick.
const TAP_BUFFER: usize = 256;
/// Frames a CAN bus's tap keeps: the bus carries several frames per
/// cycle, so the same stall needs a longer buffer.
const CAN_TAP_BUFFER: usize = hydractl_bus::CAN_RX_MAX_BUFFER;

/// Sequence numbers missing between two samples a tap received.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct Missing {
    /// Lost to a full buffer: the recorder fell behind.
    dropped: u64,
    /// Never published: the publisher skipped them.
    gaps: u64,
}

/// One service being recorded.
trait Tap {
    /// Writes every waiting sample.
    fn drain(&mut self, writer: &mut RecordingWriter) -> Result<Missing>;
}

struct TypedTap<T: Recordable> {
    reader: Reader<T>,
    channel: ChannelHandle,
    last_seq: Option<u64>,
}

impl<T: Recordable> Tap for TypedTap<T> {
    fn drain(&mut self, writer: &mut RecordingWriter) -> Result<Missing> {
        let mut count = SeqCount::default();
        while let Some(sample) = self.reader.next()? {
            count.take(
                &mut self.last_seq,
                T::KIND.sequence(bytemuck::bytes_of(&sample)).unwrap_or(0),
            );
            writer.write_sample(self.channel, &sample)?;
        }
        Ok(count.missing(TAP_BUFFER))
    }
}

/// A drain's received samples and the sequence numbers skipped between them.
#[derive(Default)]
struct SeqCount {
    received: usize,
    skipped: u64,
}

impl SeqCount {
    fn take(&mut self, last_seq: &mut Option<u64>, seq: u64) {
        self.received += 1;
        if let Some(last) = *last_seq {
            self.skipped += seq.saturating_sub(last + 1);
        }
        *last_seq = Some(last_seq.map_or(seq, |last| last.max(seq)));
    }

    /// What was skipped, for a reader that keeps `buffer` samples.
    fn missing(&self, buffer: usize) -> Missing {
        // iceoryx2 does not report an overflow; it can only have happened
        // if the buffer was full, i.e. if this drain took a whole buffer.
        if self.received >= buffer {
            Missing {
                dropped: self.skipped,
                gaps: 0,
            }
        } else {
            Missing {
                dropped: 0,
                gaps: self.skipped,
            }
        }
    }
}

/// A CAN bus's traffic: every frame the wire delivered, as
/// `can_msgs/msg/Frame` on the bus's channel.
struct CanTap {
    reader: Reader<CanFrameSample>,
    channel: ChannelHandle,
    interface: String,
    last_seq: Option<u64>,
    encoded: Vec<u8>,
}

impl Tap for CanTap {
    fn drain(&mut self, writer: &mut RecordingWriter) -> Result<Missing> {
        let mut count = SeqCount::default();
        while let Some(sample) = self.reader.next()? {
            count.take(&mut self.last_seq, sample.seq);
            self.encoded.clear();
            encode_frame(&sample, &self.interface, &mut self.encoded);
            writer.write_encoded(self.channel, sample.seq, sample.time_ns, &self.encoded)?;
        }
        Ok(count.missing(CAN_TAP_BUFFER))
    }
}

struct OpenTap<'a> {
    bus: &'a Bus,
    name: &'a str,
    writer: &'a mut RecordingWriter,
}

impl KindVisitor for OpenTap<'_> {
    type Output = Result<Box<dyn Tap>>;

    fn visit<T: Recordable>(self) -> Result<Box<dyn Tap>> {
        let reader = Reader::<T>::open(self.bus, self.name, TAP_BUFFER)?;
        let channel = self.writer.add_channel(self.name, &T::KIND)?;
        Ok(Box::new(TypedTap {
            reader,
            channel,
            last_seq: None,
        }))
    }
}

/// Records every service of a run into one recording.
pub struct Recorder {
    writer: RecordingWriter,
    taps: Vec<Box<dyn Tap>>,
    tapped: BTreeSet<String>,
    missing: Missing,
    status_seq: u64,
}

impl Recorder {
    /// Subscribes at once to the stack's own services, so that nothing of
    /// the first cycle is lost even before their publishers exist.
    pub fn new(bus: &Bus, writer: RecordingWriter) -> Result<Self> {
        let mut recorder = Self {
            writer,
            taps: Vec::new(),
            tapped: BTreeSet::new(),
            missing: Missing::default(),
            status_seq: 0,
        };
        for (name, kind) in STACK_SERVICES {
            recorder.tap(bus, name, kind.type_name)?;
        }
        Ok(recorder)
    }

    /// Taps every service of the run that discovery finds and that is not
    /// tapped yet (a hot-swapped controller's, say). Services of types we
    /// cannot decode are left alone. Returns how many were added.
    pub fn discover(&mut self, bus: &Bus) -> Result<usize> {
        let mut added = 0;
        for found in bus.scope().publish_subscribe_services()? {
            if !self.tapped.contains(&found.name) && self.tap(bus, &found.name, &found.type_name)? {
                added += 1;
            }
        }
        Ok(added)
    }

    fn tap(&mut self, bus: &Bus, name: &str, type_name: &str) -> Result<bool> {
        if type_name == CAN_FRAME_KIND.type_name {
            // What crossed the wire; each station's submissions on `…/tx`
            // are the same frames before arbitration.
            let Some(interface) = hydractl_samples::service::can_rx_interface(name) else {
                return Ok(false);
            };
            let tap = CanTap {
                reader: Reader::open(bus, name, CAN_TAP_BUFFER)?,
                channel: self.writer.add_channel(name, &CAN_FRAME_KIND)?,
                interface: interface.to_owned(),
                last_seq: None,
                encoded: Vec::with_capacity(64),
            };
            self.taps.push(Box::new(tap));
            self.tapped.insert(name.to_owned());
            return Ok(true);
        }
        let opened = visit_kind(
            type_name,
            OpenTap {
                bus,
                name,
                writer: &mut self.writer,
            },
        );
        match opened {
            Some(tap) => {
                self.taps.push(tap.with_context(|| format!("recording {name}"))?);
                self.tapped.insert(name.to_owned());
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// Writes everything waiting on every service.
    pub fn drain(&mut self) -> Result<()> {
        for tap in &mut self.taps {
            let missing = tap.drain(&mut self.writer)?;
            self.missing.dropped += missing.dropped;
            self.missing.gaps += missing.gaps;
        }
        Ok(())
    }

    /// What the writer did on its own since the last call (a full disk,
    /// parts deleted), for the recorder to say.
    pub fn take_news(&mut self) -> Vec<hydractl_recording::WriterNews> {
        self.writer.take_news()
    }

    /// Seconds from the first sample received to `ns`.
    pub fn seconds_in(&self, ns: u64) -> f64 {
        ns.saturating_sub(self.writer.first_ns().unwrap_or(ns)) as f64 * 1e-9
    }

    /// Closes the current chunk: what is written survives a kill.
    pub fn flush(&mut self) -> Result<()> {
        Ok(self.writer.flush()?)
    }

    pub fn status(&mut self, now_ns: u64) -> RecorderStatus {
        self.status_seq += 1;
        let unrecorded = self.writer.unrecorded();
        RecorderStatus {
            seq: self.status_seq - 1,
            stage_time_ns: now_ns,
            messages: self.writer.messages(),
            dropped: self.missing.dropped,
            gaps: self.missing.gaps,
            bytes: self.writer.bytes(),
            files: self.writer.files().len() as u32,
            channels: self.taps.len() as u32,
            unrecorded: unrecorded.samples,
            unrecorded_since_ns: unrecorded.since_ns.unwrap_or(0),
            disk_full: unrecorded.disk_full,
            deleted_files: self.writer.deleted_files(),
        }
    }

    /// Drains a last time and finishes the file; the files written.
    pub fn finish(mut self) -> Result<Vec<std::path::PathBuf>> {
        self.drain()?;
        Ok(self.writer.finish()?)
    }
}

/// Puts recorded samples back on one service.
pub trait Republisher {
    /// Publishes a sample from its recorded bytes.
    fn publish(&self, payload: &[u8]) -> Result<()>;
}

struct TypedRepublisher<T: Recordable> {
    outlet: Outlet<T>,
}

impl<T: Recordable> Republisher for TypedRepublisher<T> {
    fn publish(&self, payload: &[u8]) -> Result<()> {
        // The reader checked each payload's size against its schema.
        let sample: T = bytemuck::pod_read_unaligned(payload);
        Ok(self.outlet.publish(sample)?)
    }
}

struct OpenRepublisher<'a> {
    bus: &'a Bus,
    name: &'a str,
}

impl KindVisitor for OpenRepublisher<'_> {
    type Output = Result<Box<dyn Republisher>>;

    fn visit<T: Recordable>(self) -> Result<Box<dyn Republisher>> {
        Ok(Box::new(TypedRepublisher {
            outlet: Outlet::<T>::open(self.bus, self.name)?,
        }))
    }
}

/// A publisher (and notifier) for recorded samples of `type_name` on `name`;
/// `None` for a type hydractl does not know.
pub fn republisher(bus: &Bus, name: &str, type_name: &str) -> Option<Result<Box<dyn Republisher>>> {
    visit_kind(type_name, OpenRepublisher { bus, name })
}
