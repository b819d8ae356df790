//! Handovers are never lost: thousands of them, plant and controller
//! handovers mixed on the one service, published in bursts faster than the
//! processes read while every CPU is busy (each burst waiting for the last
//! one's answers, as the supervisor does), each read once, in order, and
//! acknowledged.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hydractl_bus::{clock, Bus, Outlet, OwnedScope, Reader};
use hydractl_processes::handover::HandoverInbox;
use hydractl_samples::{code, service, Handover, HandoverAck};

const HANDOVERS: u64 = 4000;
const STAGES: [u32; 3] = [code::STAGE_POSITION, code::STAGE_TORQUE, code::STAGE_PLANT];

#[test]
fn thousands_of_handovers_under_load_are_each_read_once_in_order_and_acknowledged() {
    let scope = OwnedScope::fresh(&format!("t{}_handq_", std::process::id() % 100_000)).expect("prefix");
    let stop = Arc::new(AtomicBool::new(false));
    // Every CPU busy.
    let load: Vec<_> = (0..std::thread::available_parallelism().map_or(2, |n| n.get()))
        .map(|_| {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
                    std::hint::black_box(x);
                }
            })
        })
        .collect();
    let supervisor = Bus::open(&scope, "supervisor").expect("node");
    let handovers: Outlet<Handover> = Outlet::open(&supervisor, service::HANDOVER).expect("outlet");
    let acks: Reader<HandoverAck> = Reader::open(&supervisor, service::HANDOVER_ACK, 256).expect("acks");
    // Each stage's process reads once a period, as the loop's processes do.
    // A handover from before a process started is old news to it, so the
    // first one is published only once every reader is open: on a loaded
    // machine a thread may take far longer than any fixed pause to start.
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let readers: Vec<_> = STAGES
        .iter()
        .map(|&stage| {
            let (scope, stop, ready) = (scope.clone(), stop.clone(), ready_tx.clone());
            std::thread::spawn(move || {
                let bus = Bus::open(&scope, "reader").expect("node");
                let mut inbox = HandoverInbox::open(&bus, stage).expect("inbox");
                ready.send(()).expect("ready");
                let mut seen = Vec::new();
                while !stop.load(Ordering::Relaxed) {
                    while let Some(h) = inbox.next_handover().expect("read") {
                        seen.push(h.seq);
                    }
                    std::thread::sleep(Duration::from_millis(1));
                }
                while let Some(h) = inbox.next_handover().expect("read") {
                    seen.push(h.seq);
                }
                drop(inbox);
                seen
            })
        })
        .collect();
    for _ in STAGES {
        ready_rx
            .recv_timeout(Duration::from_secs(60))
            .expect("every reader open");
    }
    std::thread::sleep(Duration::from_millis(1));
    let mut acked = 0u64;
    let mut expected: Vec<Vec<u64>> = vec![Vec::new(); STAGES.len()];
    for seq in 0..HANDOVERS {
        let stage = (seq * 7 % 3) as usize;
        handovers
            .publish(Handover {
                seq,
                stage_time_ns: clock::now_ns(),
                at_seq: seq,
                new_pid: 1,
                stage: STAGES[stage],
                ..Handover::default()
            })
            .expect("publish");
        expected[stage].push(seq);
        while acks.next().expect("acks").is_some() {
            acked += 1;
        }
        // Bursts of 16, far faster than a reader's period and far more than
        // the supervisor ever has in flight; like the supervisor, the next
        // burst waits for this one's answers. Every burst names all three
        // stages, so no reader's queue ever holds more than one burst.
        if seq % 16 == 15 {
            let deadline = Instant::now() + Duration::from_secs(5);
            while acked <= seq && Instant::now() < deadline {
                while acks.next().expect("acks").is_some() {
                    acked += 1;
                }
                std::thread::sleep(Duration::from_micros(200));
            }
            // A lost answer would make every later burst wait its full
            // deadline: fail at once, naming the burst.
            if acked <= seq {
                stop.store(true, Ordering::Relaxed);
                panic!("burst ending at handover {seq}: {acked} answers after 5 s");
            }
        }
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    while acked < HANDOVERS && Instant::now() < deadline {
        while acks.next().expect("acks").is_some() {
            acked += 1;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    stop.store(true, Ordering::Relaxed);
    let seen: Vec<Vec<u64>> = readers.into_iter().map(|r| r.join().expect("reader")).collect();
    load.into_iter().for_each(|l| l.join().expect("load"));
    for (stage, (seen, expected)) in seen.iter().zip(&expected).enumerate() {
        assert_eq!(seen, expected, "stage {stage}: every handover, once, in order");
    }
    assert_eq!(acked, HANDOVERS, "every handover acknowledged");
    drop((handovers, acks, supervisor));
    scope.clean_stale().expect("clean");
}
