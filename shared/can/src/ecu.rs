//! Simulated ECUs: the machine's CAN nodes as their manuals describe
//! them, driven by frames and the clock, and by the physics for what they
//! measure. Each answers NMT, sends its heartbeat, and (once operational)
//! its TPDO on every SYNC; the valve runs its CiA 408 state machine,
//! follows the set point only when Active, and falls to hold with an EMCY
//! when the set point stops coming. Plain state, no I/O: the `ecus`
//! process or a test moves the frames.

use crate::canopen::{
    self, cob_id, decode_nmt, emcy_code, Emergency, NmtCommand, NmtState, NodeId, SdoRequest, SdoResponse,
};
use crate::heartbeat::HEARTBEAT_PRODUCER;
use crate::profile::{PressureChannel, Profile};
use crate::valve::{self, object as valve_object, DeviceState, StateMachine};
use crate::Frame;

/// Frames one ECU may send in answer to one event.
pub(crate) const OUTBOX: usize = 4;

/// What an ECU sends in answer to one frame or tick; fixed size.
#[derive(Debug, Clone, Copy, Default)]
pub struct Outbox {
    frames: [Frame; OUTBOX],
    count: usize,
}

impl Outbox {
    pub fn push(&mut self, frame: Frame) {
        if self.count < OUTBOX {
            self.frames[self.count] = frame;
            self.count += 1;
        }
    }

    pub fn frames(&self) -> &[Frame] {
        &self.frames[..self.count]
    }

    pub fn clear(&mut self) {
        self.count = 0;
    }
}

/// The CiA 301 part every node shares: NMT state and heartbeat.
#[derive(Debug, Clone, Copy)]
struct NodeCore {
    node: NodeId,
    state: NmtState,
    heartbeat_ns: u64,
    next_heartbeat_ns: u64,
    booted: bool,
}

impl NodeCore {
    fn new(node: NodeId, heartbeat_ms: u16) -> Self {
        Self {
            node,
            state: NmtState::PreOperational,
            heartbeat_ns: u64::from(heartbeat_ms) * 1_000_000,
            next_heartbeat_ns: 0,
            booted: false,
        }
    }

    /// Boot-up message first, then the heartbeat at its period.
    fn tick(&mut self, now_ns: u64, out: &mut Outbox) {
        if !self.booted {
            self.booted = true;
            out.push(canopen::heartbeat(self.node, NmtState::BootUp));
            self.next_heartbeat_ns = now_ns + self.heartbeat_ns;
            return;
        }
        if self.heartbeat_ns > 0 && now_ns >= self.next_heartbeat_ns {
            out.push(canopen::heartbeat(self.node, self.state));
            self.next_heartbeat_ns = now_ns + self.heartbeat_ns;
        }
    }

    /// An NMT command for this node or all; true when it was one.
    fn on_nmt(&mut self, frame: &Frame) -> Option<NmtCommand> {
        let (command, node) = decode_nmt(frame).ok()?;
        if node != 0 && node != self.node {
            return None;
        }
        self.state = match command {
            NmtCommand::Start => NmtState::Operational,
            NmtCommand::Stop => NmtState::Stopped,
            NmtCommand::EnterPreOperational => NmtState::PreOperational,
            NmtCommand::ResetNode | NmtCommand::ResetCommunication => {
                self.booted = false;
                NmtState::PreOperational
            }
        };
        Some(command)
    }

    fn operational(&self) -> bool {
        self.state == NmtState::Operational
    }

    /// The communication objects every node serves by SDO: the heartbeat
    /// producer time (0x1017), which the master sets at boot. `None` for
    /// any other object.
    fn answer_sdo(&mut self, request: SdoRequest) -> Option<SdoResponse> {
        match request {
            SdoRequest::Download {
                index: HEARTBEAT_PRODUCER,
                sub: 0,
                value,
                ..
            } => {
                self.heartbeat_ns = u64::from(u16::from_le_bytes([value[0], value[1]])) * 1_000_000;
                // The new period counts from now: the next beat at once.
                self.next_heartbeat_ns = 0;
                Some(SdoResponse::Downloaded {
                    index: HEARTBEAT_PRODUCER,
                    sub: 0,
                })
            }
            SdoRequest::Upload {
                index: HEARTBEAT_PRODUCER,
                sub: 0,
            } => Some(SdoResponse::Uploaded {
                index: HEARTBEAT_PRODUCER,
                sub: 0,
                value: ((self.heartbeat_ns / 1_000_000) as u32).to_le_bytes(),
                len: 2,
            }),
            _ => None,
        }
    }
}

/// The heartbeat producer time a node boots with until the master sets
/// its own (the PVED-CC's default): longer than the master's consumer
/// timeout, so a master that forgets to set it finds every node lost.
pub(crate) const FACTORY_HEARTBEAT_MS: u16 = 1000;

/// Object 0x1400 + n − 1: RPDO n's communication parameters.
pub(crate) const RPDO_COMMUNICATION: u16 = 0x1400;
/// Its sub-index 5, the event timer: for an RPDO, CiA 301's deadline
/// monitoring (no PDO for this long: EMCY 0x8250, and the device's fault
/// reaction), ms (UNSIGNED16).
pub(crate) const RPDO_EVENT_TIMER: u8 = 5;
/// SDO abort: the object does not exist in the object dictionary.
const NO_SUCH_OBJECT: u32 = 0x0602_0000;

/// A CiA 408 proportional valve (as the PVED-CC behaves).
#[derive(Debug, Clone, Copy)]
pub struct ValveEcu {
    core: NodeCore,
    dsm: StateMachine,
    profile_set_point: crate::profile::Pdo,
    profile_control: crate::profile::Pdo,
    profile_status: crate::profile::Pdo,
    status_word_at: (usize, u8),
    sync_cob_id: u16,
    device_mode_bus: bool,
    set_point: i16,
    last_set_point_ns: Option<u64>,
    rpdo_timeout_ns: u64,
    /// The set point's RPDO number (1 to 4): its timer is object
    /// 0x1400 + number − 1, sub-index 5.
    set_point_rpdo: u8,
    /// Whether the master may write the timeout by SDO (a valve whose
    /// timeout only the vendor's tool sets refuses).
    timeout_settable: bool,
    /// The spool's position, ±16384, from the physics.
    actual: i16,
    emcys: u64,
}

impl ValveEcu {
    pub fn new(profile: &Profile) -> Self {
        Self {
            core: NodeCore::new(profile.valve, FACTORY_HEARTBEAT_MS),
            dsm: StateMachine::power_up(),
            profile_set_point: profile.valve_set_point,
            profile_control: profile.valve_control,
            profile_status: profile.valve_status,
            status_word_at: profile.valve_status_word_at,
            sync_cob_id: profile.sync_cob_id,
            device_mode_bus: false,
            set_point: 0,
            last_set_point_ns: None,
            rpdo_timeout_ns: u64::from(profile.valve_rpdo_timeout_ms) * 1_000_000,
            set_point_rpdo: profile.valve_set_point_rpdo,
            timeout_settable: true,
            actual: 0,
            emcys: 0,
        }
    }

    pub fn state(&self) -> DeviceState {
        self.dsm.state()
    }

    /// A valve whose timeout only the vendor's tool sets, at `timeout_ms`:
    /// it refuses the master's SDO write and reads back its own value.
    pub fn with_fixed_timeout(mut self, timeout_ms: u16) -> Self {
        self.timeout_settable = false;
        self.rpdo_timeout_ns = u64::from(timeout_ms) * 1_000_000;
        self
    }

    fn set_point_rpdo_object(&self) -> u16 {
        RPDO_COMMUNICATION + u16::from(self.set_point_rpdo) - 1
    }

    pub fn nmt_state(&self) -> NmtState {
        self.core.state
    }

    pub fn emcys(&self) -> u64 {
        self.emcys
    }

    /// The spool command in [-1, 1] the valve's own electronics follow:
    /// the set point in Active with the device mode on the bus, neutral
    /// in every other state.
    pub fn spool_command(&self) -> f64 {
        if self.dsm.state().follows_set_point() && self.device_mode_bus && self.core.operational() {
            valve::spool_position(self.set_point)
        } else {
            0.0
        }
    }

    /// The spool's measured position, for the status TPDO.
    pub fn set_actual(&mut self, spool: f64) {
        self.actual = valve::set_point(spool);
    }

    pub fn on_frame(&mut self, frame: &Frame, now_ns: u64, out: &mut Outbox) {
        // A remote request carries no data: taken as a set point it would
        // hide a dead master from the RPDO timeout.
        if frame.is_error() || frame.is_extended() || frame.is_remote() {
            return;
        }
        if self.core.on_nmt(frame).is_some() {
            if !self.core.operational() {
                // Leaving operational stops the PDOs: the valve holds.
                self.fault_if_active(out);
            }
            return;
        }
        let id = frame.id as u16;
        if canopen::is_sync(frame, self.sync_cob_id) {
            if self.core.operational() {
                if let Ok(f) = self.status_frame() {
                    out.push(f);
                }
            }
            return;
        }
        if !self.core.operational() && (id == self.profile_set_point.cob_id || id == self.profile_control.cob_id) {
            return;
        }
        if id == self.profile_set_point.cob_id {
            // A PDO of the wrong length is not processed (CiA 301).
            if let Ok(values) = self.profile_set_point.mapping.unpack(frame, "valve set point RPDO") {
                let slot = self.profile_set_point.slot(self.profile_set_point.value_at);
                self.set_point = canopen::signed(values[slot], 16) as i16;
                self.last_set_point_ns = Some(now_ns);
            } else {
                out.push(Emergency::new(emcy_code::PDO_LENGTH, 0x11).to_frame(self.core.node));
                self.emcys += 1;
            }
            return;
        }
        if id == self.profile_control.cob_id {
            if let Ok(values) = self.profile_control.mapping.unpack(frame, "valve control RPDO") {
                let word = values[self.profile_control.slot(self.profile_control.value_at)] as u16;
                if let Some((offset, _)) = self.profile_control.mapping.locate(valve_object::DEVICE_MODE, 0) {
                    let mode = values[self.profile_control.slot((offset, 8))] as u8;
                    self.device_mode_bus = mode == valve_object::DEVICE_MODE_BUS;
                }
                self.on_control_word(word, now_ns);
            }
            return;
        }
        if id == cob_id::sdo_request(self.core.node) {
            if let Ok((_, request)) = SdoRequest::decode(frame) {
                out.push(self.answer_sdo(request, now_ns).to_frame(self.core.node));
            }
        }
    }

    /// The valve's own clock: heartbeat, and the RPDO timeout in Active.
    pub fn tick(&mut self, now_ns: u64, out: &mut Outbox) {
        self.core.tick(now_ns, out);
        let silent = self
            .last_set_point_ns
            .is_none_or(|t| now_ns.saturating_sub(t) > self.rpdo_timeout_ns);
        if silent {
            self.fault_if_active(out);
        }
    }

    /// The set point stopped (timeout, or the node left operational): to
    /// fault hold, spool neutral, one EMCY.
    fn fault_if_active(&mut self, out: &mut Outbox) {
        if self.dsm.state() == DeviceState::Active && self.dsm.on_fault() {
            self.set_point = 0;
            out.push(Emergency::new(emcy_code::VALVE_RPDO_TIMEOUT, 0x11).to_frame(self.core.node));
            self.emcys += 1;
        }
    }

    /// A control word by PDO or SDO; the set point's timer starts with Active.
    fn on_control_word(&mut self, word: u16, now_ns: u64) {
        let before = self.dsm.state();
        if self.dsm.on_control_word(word) == DeviceState::Active && before != DeviceState::Active {
            self.last_set_point_ns = Some(now_ns);
        }
    }

    fn status_frame(&self) -> Result<Frame, crate::CanError> {
        let mut values = [0u64; 8];
        let n = self.profile_status.mapping.entries().len();
        values[self.profile_status.slot(self.status_word_at)] = u64::from(self.dsm.state().status_word());
        values[self.profile_status.slot(self.profile_status.value_at)] = valve::raw_i16(self.actual);
        self.profile_status
            .mapping
            .pack(self.profile_status.cob_id, &values[..n])
    }

    fn answer_sdo(&mut self, request: SdoRequest, now_ns: u64) -> SdoResponse {
        if let Some(answer) = self.core.answer_sdo(request) {
            return answer;
        }
        match request {
            SdoRequest::Upload { index, sub } => {
                let value: Option<u32> = match (index, sub) {
                    (valve_object::DEVICE_TYPE, 0) => Some(valve_object::DEVICE_TYPE_VALUE),
                    (valve_object::STATUS_WORD, 0) => Some(u32::from(self.dsm.state().status_word())),
                    (valve_object::DEVICE_MODE, 0) => Some(u32::from(self.device_mode_bus)),
                    (valve_object::ACTUAL_VALUE, 1) => Some(u32::from(self.actual as u16)),
                    (index, RPDO_EVENT_TIMER) if index == self.set_point_rpdo_object() => {
                        Some((self.rpdo_timeout_ns / 1_000_000) as u32)
                    }
                    _ => None,
                };
                match value {
                    Some(v) => SdoResponse::Uploaded {
                        index,
                        sub,
                        value: v.to_le_bytes(),
                        len: 4,
                    },
                    None => SdoResponse::Aborted {
                        index,
                        sub,
                        code: NO_SUCH_OBJECT,
                    },
                }
            }
            SdoRequest::Download { index, sub, value, .. } => match (index, sub) {
                (valve_object::CONTROL_WORD, 0) => {
                    self.on_control_word(u16::from_le_bytes([value[0], value[1]]), now_ns);
                    SdoResponse::Downloaded { index, sub }
                }
                (valve_object::DEVICE_MODE, 0) => {
                    self.device_mode_bus = value[0] == valve_object::DEVICE_MODE_BUS;
                    SdoResponse::Downloaded { index, sub }
                }
                (index, RPDO_EVENT_TIMER) if index == self.set_point_rpdo_object() && self.timeout_settable => {
                    self.rpdo_timeout_ns = u64::from(u16::from_le_bytes([value[0], value[1]])) * 1_000_000;
                    SdoResponse::Downloaded { index, sub }
                }
                _ => SdoResponse::Aborted {
                    index,
                    sub,
                    code: NO_SUCH_OBJECT,
                },
            },
        }
    }
}

/// A sensor node that answers every SYNC with one measured value: the
/// angle encoder (CiA 406) or a pressure transducer (CiA 404).
#[derive(Debug, Clone, Copy)]
pub struct SensorEcu {
    core: NodeCore,
    pdo: crate::profile::Pdo,
    sync_cob_id: u16,
    raw: u64,
}

impl SensorEcu {
    pub fn encoder(profile: &Profile) -> Self {
        Self {
            core: NodeCore::new(profile.encoder, FACTORY_HEARTBEAT_MS),
            pdo: profile.encoder_position,
            sync_cob_id: profile.sync_cob_id,
            raw: 0,
        }
    }

    pub fn transducer(profile: &Profile, channel: &PressureChannel) -> Self {
        Self {
            core: NodeCore::new(channel.node, FACTORY_HEARTBEAT_MS),
            pdo: channel.value,
            sync_cob_id: profile.sync_cob_id,
            raw: 0,
        }
    }

    pub fn node(&self) -> NodeId {
        self.core.node
    }

    pub fn nmt_state(&self) -> NmtState {
        self.core.state
    }

    /// The raw value the next TPDO carries (already quantized and scaled
    /// by the device's profile).
    pub fn measure(&mut self, raw: u64) {
        self.raw = raw;
    }

    pub fn on_frame(&mut self, frame: &Frame, out: &mut Outbox) {
        if frame.is_error() || frame.is_extended() || frame.is_remote() {
            return;
        }
        if self.core.on_nmt(frame).is_some() {
            return;
        }
        if frame.id == u32::from(cob_id::sdo_request(self.core.node)) {
            if let Ok((_, request)) = SdoRequest::decode(frame) {
                let answer = self.core.answer_sdo(request).unwrap_or(SdoResponse::Aborted {
                    index: match request {
                        SdoRequest::Download { index, .. } | SdoRequest::Upload { index, .. } => index,
                    },
                    sub: match request {
                        SdoRequest::Download { sub, .. } | SdoRequest::Upload { sub, .. } => sub,
                    },
                    code: NO_SUCH_OBJECT,
                });
                out.push(answer.to_frame(self.core.node));
            }
            return;
        }
        if canopen::is_sync(frame, self.sync_cob_id) && self.core.operational() {
            let n = self.pdo.mapping.entries().len();
            let mut values = [0u64; 8];
            values[0] = self.raw;
            if let Ok(f) = self.pdo.mapping.pack(self.pdo.cob_id, &values[..n]) {
                out.push(f);
            }
        }
    }

    pub fn tick(&mut self, now_ns: u64, out: &mut Outbox) {
        self.core.tick(now_ns, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::nmt;
    use crate::heartbeat::{set_heartbeat, HeartbeatWatch};
    use crate::profile::CanConfig;
    use crate::valve::next_control_word;
    use crate::wire::Wire;

    const MS: u64 = 1_000_000;

    fn profile() -> Profile {
        CanConfig::default().resolve().expect("defaults")
    }

    fn control(profile: &Profile, word: u16) -> Frame {
        profile
            .valve_control
            .mapping
            .pack(profile.valve_control.cob_id, &[u64::from(word), 1])
            .expect("control")
    }

    fn set_point(profile: &Profile, command: f64) -> Frame {
        profile
            .valve_set_point
            .mapping
            .pack(
                profile.valve_set_point.cob_id,
                &[0, valve::raw_i16(valve::set_point(command))],
            )
            .expect("set point")
    }

    /// Master and valve over the wire, millisecond by millisecond.
    struct Bench {
        profile: Profile,
        wire: Wire,
        valve: ValveEcu,
        now: u64,
        heard: Vec<Frame>,
    }

    impl Bench {
        fn new() -> Self {
            let profile = profile();
            Self {
                wire: Wire::new(profile.bitrate),
                valve: ValveEcu::new(&profile),
                profile,
                now: 0,
                heard: Vec::new(),
            }
        }

        /// The master sends `frames`, then a millisecond passes.
        fn step(&mut self, frames: &[Frame]) {
            for f in frames {
                self.wire.submit(*f, 1, self.now);
            }
            let mut out = Outbox::default();
            self.valve.tick(self.now, &mut out);
            for f in out.frames() {
                self.wire.submit(*f, 2, self.now);
            }
            let end = self.now + MS;
            while let Some(next) = self.wire.next_event_ns().filter(|&t| t <= end) {
                while let Some(d) = self.wire.poll(next) {
                    if d.station == 2 {
                        self.heard.push(d.frame);
                    } else {
                        let mut out = Outbox::default();
                        self.valve.on_frame(&d.frame, d.end_ns, &mut out);
                        for f in out.frames() {
                            self.wire.submit(*f, 2, d.end_ns);
                        }
                    }
                }
            }
            self.now = end;
        }

        fn status(&self) -> Option<DeviceState> {
            self.heard
                .iter()
                .rev()
                .find(|f| f.id == u32::from(self.profile.valve_status.cob_id))
                .map(|f| DeviceState::from_status_word(u16::from_le_bytes([f.data[0], f.data[1]]), true))
        }
    }

    #[test]
    fn the_valve_is_brought_up_and_follows_the_set_point_only_when_active() {
        let mut bench = Bench::new();
        bench.step(&[]);
        assert_eq!(
            bench.heard[0],
            canopen::heartbeat(0x10, NmtState::BootUp),
            "boot-up first"
        );
        let sync = canopen::sync(cob_id::SYNC, None);
        bench.step(&[nmt(NmtCommand::Start, 0), sync]);
        assert_eq!(bench.valve.nmt_state(), NmtState::Operational);
        assert_eq!(bench.status(), Some(DeviceState::Init));
        // A set point before Active moves nothing.
        bench.step(&[set_point(&bench.profile, 0.5), sync]);
        assert_eq!(bench.valve.spool_command(), 0.0);
        // The status answers the SYNC, which wins arbitration over the
        // control word: it lags a step, and the master repeats its word
        // until the status confirms it.
        for _ in 0..10 {
            let state = bench.status().expect("status");
            if state == DeviceState::Active {
                break;
            }
            let word = next_control_word(state).expect("no fault");
            let frames = [control(&bench.profile, word), set_point(&bench.profile, 0.0), sync];
            bench.step(&frames);
        }
        assert_eq!(bench.status(), Some(DeviceState::Active));
        bench.step(&[set_point(&bench.profile, 0.5), sync]);
        assert!((bench.valve.spool_command() - 0.5).abs() < 1e-4);
    }

    #[test]
    fn a_silent_master_faults_the_valve_to_hold_with_an_emcy_and_a_reset_recovers_it() {
        let mut bench = Bench::new();
        let sync = canopen::sync(cob_id::SYNC, None);
        bench.step(&[nmt(NmtCommand::Start, 0x10)]);
        for word in [0x09, 0x0B, 0x0F] {
            let frames = [control(&bench.profile, word), set_point(&bench.profile, 0.3), sync];
            bench.step(&frames);
        }
        assert!((bench.valve.spool_command() - 0.3).abs() < 1e-4);
        // The master dies: 20 ms of nothing.
        for _ in 0..25 {
            bench.step(&[]);
        }
        assert_eq!(bench.valve.state(), DeviceState::FaultHold);
        assert_eq!(bench.valve.spool_command(), 0.0);
        let emcy = bench
            .heard
            .iter()
            .find_map(|f| Emergency::decode(f).ok())
            .expect("an EMCY");
        assert_eq!(emcy, (0x10, Emergency::new(emcy_code::VALVE_RPDO_TIMEOUT, 0x11)));
        assert_eq!(bench.valve.emcys(), 1, "once");
        // Back: R low, R high, active.
        for word in [0x03, 0x0B, 0x0F] {
            let frames = [control(&bench.profile, word), set_point(&bench.profile, -0.2), sync];
            bench.step(&frames);
        }
        assert_eq!(bench.valve.state(), DeviceState::Active);
        assert!((bench.valve.spool_command() + 0.2).abs() < 1e-4);
    }

    #[test]
    fn a_set_point_of_the_wrong_length_is_refused_with_an_emcy() {
        let mut bench = Bench::new();
        bench.step(&[nmt(NmtCommand::Start, 0)]);
        for word in [0x09, 0x0B, 0x0F] {
            bench.step(&[control(&bench.profile, word), set_point(&bench.profile, 0.4)]);
        }
        let garbled = Frame::new(bench.profile.valve_set_point.cob_id, &[0, 0, 0xFF]).expect("frame");
        let remote = Frame::remote(bench.profile.valve_set_point.cob_id, 4).expect("frame");
        bench.step(&[garbled, remote]);
        assert!(
            (bench.valve.spool_command() - 0.4).abs() < 1e-4,
            "neither the garbled one nor a remote request is taken"
        );
        assert!(bench
            .heard
            .iter()
            .filter_map(|f| Emergency::decode(f).ok())
            .any(|(_, e)| e.code == emcy_code::PDO_LENGTH));
        // Nor does a remote request keep a dead master's valve alive.
        for _ in 0..25 {
            bench.step(&[remote]);
        }
        assert_eq!(bench.valve.state(), DeviceState::FaultHold);
    }

    #[test]
    fn sensors_answer_sync_only_when_operational_and_heartbeats_are_watched() {
        let profile = profile();
        let mut encoder = SensorEcu::encoder(&profile);
        let mut out = Outbox::default();
        encoder.measure(u64::from(profile.encoder_scale.position(1.0)));
        encoder.on_frame(&canopen::sync(cob_id::SYNC, None), &mut out);
        assert!(out.frames().is_empty(), "pre-operational: no PDO");
        encoder.on_frame(&nmt(NmtCommand::Start, 0), &mut out);
        encoder.on_frame(&canopen::sync(cob_id::SYNC, None), &mut out);
        let tpdo = out.frames()[0];
        assert_eq!(tpdo.id, 0x1A0);
        let raw = profile
            .encoder_position
            .mapping
            .unpack(&tpdo, "encoder")
            .expect("unpack")[0];
        assert!((profile.encoder_scale.angle(raw as u32) - 1.0).abs() <= profile.encoder_scale.resolution());

        let mut watch = HeartbeatWatch::new(0x20, 300);
        let mut out = Outbox::default();
        encoder.on_frame(&set_heartbeat(0x20, 100), &mut out);
        let mut out = Outbox::default();
        encoder.tick(0, &mut out);
        encoder.tick(100 * MS, &mut out);
        for f in out.frames() {
            assert!(watch.on_frame(f, 100 * MS));
        }
        assert_eq!(watch.state(), Some(NmtState::Operational));
        assert!(!watch.lost(350 * MS));
        assert!(watch.lost(401 * MS));
        assert!(
            !HeartbeatWatch::new(0x30, 300).lost(u64::MAX),
            "never heard is not lost"
        );
        // The master sets the producer time at boot (a PVED-CC ships with
        // 1000 ms): the node answers and beats at the new period.
        let mut out = Outbox::default();
        encoder.on_frame(&set_heartbeat(0x20, 50), &mut out);
        assert_eq!(
            SdoResponse::decode(&out.frames()[0]).map(|(_, r)| r),
            Ok(SdoResponse::Downloaded {
                index: HEARTBEAT_PRODUCER,
                sub: 0
            })
        );
        let mut out = Outbox::default();
        encoder.tick(150 * MS, &mut out);
        encoder.tick(170 * MS, &mut out);
        assert_eq!(out.frames().len(), 1, "one beat at 150 ms, the next due at 200 ms");
    }
}
