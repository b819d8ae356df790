//! `hydractl bench latency`: the five stages (sensor → friction → position
//! → torque → valve), with their real algorithms, run three ways in one
//! run: as separate processes over iceoryx2 (as deployed), as separate
//! processes over UDP loopback sockets, and as plain function calls in one
//! process (the floor). A driver stands in for the plant: it sends one
//! reading per millisecond and times its way back from the valve stage.
//! Every service also has `--observers` readers that only look, as the
//! live stack's recorder, supervisor and monitor do.

use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hydractl_bus::{clock, quiet_ipc_logging, Bus, Inlet, Outlet, Reader, RunScope, Wakeup, PREFIX_ENV};
use hydractl_config::Config;
use hydractl_samples::BenchSample;

use crate::slowest::Slowest;

mod semaphore_service;
use semaphore_service::{SemaphoreInlet, SemaphoreOutlet, SemaphoreReader, SemaphoreWaker, MAX_OBSERVERS};
mod stage;
use stage::Stage;
pub use stage::{stage, StageArgs};

pub(crate) use hydractl_samples::service::STAGES;
/// `iceoryx2` is the live stack's: samples in shared memory, each hop woken
/// by its service's doorbell (a futex); `iceoryx2-events` wakes each hop
/// with iceoryx2's own events (a datagram on a unix socket, `ppoll`);
/// `iceoryx2-sem` with iceoryx2's semaphore events.
const TRANSPORTS: [&str; 5] = ["iceoryx2", "iceoryx2-events", "iceoryx2-sem", "udp", "calls"];
pub(crate) const SERVICES: [&str; 6] = [
    "hydractl/bench/0",
    "hydractl/bench/1",
    "hydractl/bench/2",
    "hydractl/bench/3",
    "hydractl/bench/4",
    "hydractl/bench/5",
];

#[derive(clap::Args)]
pub struct LatencyArgs {
    /// Seconds per transport.
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
    /// The transports take turns in this many rounds, each a share of the
    /// duration, so that drifting machine noise falls on all alike.
    #[arg(long, default_value_t = 5)]
    rounds: usize,
    /// Run only this transport: iceoryx2 (as the live stack: doorbells),
    /// iceoryx2-events (iceoryx2's unix-datagram events), iceoryx2-sem
    /// (iceoryx2's semaphore events), udp or calls.
    #[arg(long)]
    only: Option<String>,
    /// The config whose stages, CPU, priority and idle latency are
    /// measured (default: the simulated default).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Readers of every service besides the next stage, that only look:
    /// in the live stack the recorder, the supervisor and `hydractl run`'s
    /// monitor read every sample (3). Over iceoryx2 a sample is written
    /// once for all; over UDP each reader costs its own datagram.
    #[arg(long, default_value_t = 3)]
    observers: usize,
}

/// A stage process of the benchmark (started by `bench latency`).
/// Sends `s` into the chain and waits up to `within` for it to come back
/// from the valve stage; `None` when it did not (a miss).
pub(crate) fn round_trip(
    first: &Outlet<BenchSample>,
    last: &Inlet<BenchSample>,
    s: &BenchSample,
    within: Duration,
) -> Result<Option<BenchSample>> {
    first.publish(*s)?;
    let deadline = Instant::now() + within;
    while Instant::now() < deadline {
        if let Some(back) = last.wait_latest(deadline.saturating_duration_since(Instant::now()))? {
            if back.seq == s.seq {
                return Ok(Some(back));
            }
        }
    }
    Ok(None)
}

/// The reading the driver sends for cycle `seq`: a slow sweep, so the
/// stages compute real values.
fn reading(seq: u64) -> BenchSample {
    let t = seq as f64 * 1e-3;
    BenchSample {
        seq,
        stamps_ns: [clock::now_ns(), 0, 0, 0, 0, 0],
        angle: 0.2 * (2.0 * t).sin(),
        p_a: 80e5 + 5e5 * (3.0 * t).sin(),
        p_b: 80e5,
        ..BenchSample::default()
    }
}

pub(crate) struct Results {
    name: &'static str,
    /// End-to-end, ns.
    total: Vec<u64>,
    /// Per hop i (driver → stage 1, …, stage 5 → driver), ns.
    hops: [Vec<u64>; 6],
    pub(crate) misses: u64,
    /// The slowest cycles, slowest first: end-to-end and per hop, ns. A
    /// stall is told apart by the hop it happened in.
    slowest: Slowest<[u64; 6], 3>,
}

impl Results {
    fn new(name: &'static str, capacity: usize) -> Self {
        Self {
            name,
            total: Vec::with_capacity(capacity),
            hops: std::array::from_fn(|_| Vec::with_capacity(capacity)),
            misses: 0,
            slowest: Slowest::default(),
        }
    }

    /// Adds another round's results of the same transport.
    fn absorb(&mut self, round: Results) {
        self.total.extend(round.total);
        for (hops, more) in self.hops.iter_mut().zip(round.hops) {
            hops.extend(more);
        }
        self.misses += round.misses;
        for (total, hops) in round.slowest.iter() {
            self.slowest.keep(*total, *hops);
        }
    }

    fn record(&mut self, s: &BenchSample, received_ns: u64) {
        let total = received_ns.saturating_sub(s.stamps_ns[0]);
        self.total.push(total);
        if total > 1_000_000 {
            self.misses += 1;
        }
        let mut hops = [0; 6];
        for (i, hop) in hops.iter_mut().enumerate() {
            let end = s.stamps_ns.get(i + 1).copied().unwrap_or(received_ns);
            *hop = end.saturating_sub(s.stamps_ns[i]);
            self.hops[i].push(*hop);
        }
        self.slowest.keep(total, hops);
    }
}

fn quantile_us(sorted: &[u64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[i] as f64 / 1000.0
}

pub fn bench(args: LatencyArgs) -> Result<()> {
    if args.observers > MAX_OBSERVERS {
        bail!(
            "--observers {}: a service takes at most {MAX_OBSERVERS}",
            args.observers
        );
    }
    quiet_ipc_logging();
    let config = Config::load_or_default(args.config.as_deref())?;
    for e in hydractl_rt::enter_loop(config.timing.loop_cpu, config.timing.realtime_priority) {
        tracing::warn!("{e}");
    }
    // Held for the benchmark as `hydractl run` holds them for a run.
    let timing = &config.timing;
    let (reservation, refusals) = hydractl_rt::reserve_for_run(
        timing.loop_cpu,
        timing.cpu_dma_latency_us,
        timing.interrupts_off_loop_cpu,
    );
    for e in refusals {
        tracing::warn!("{e}");
    }
    let stage_config = args.config.as_deref();
    let rounds = args.rounds.max(1);
    let cycles_per_round = (args.duration * config.timing.control_rate_hz / rounds as f64)
        .round()
        .max(1.0) as u64;
    let transports: Vec<&str> = TRANSPORTS
        .into_iter()
        .filter(|name| args.only.as_deref().is_none_or(|only| only == *name))
        .collect();
    if transports.is_empty() {
        bail!(
            "--only: no transport `{}`; one of {}",
            args.only.unwrap_or_default(),
            TRANSPORTS.join(", ")
        );
    }
    let mut all: Vec<Results> = transports
        .iter()
        .map(|name| Results::new(name, (cycles_per_round * rounds as u64) as usize))
        .collect();
    // The transports take turns, round by round: this machine's noise
    // drifts over minutes, and one transport measured after another would
    // be compared across different weather.
    for _ in 0..rounds {
        for (name, results) in transports.iter().zip(all.iter_mut()) {
            let round = match *name {
                "iceoryx2" => run_iceoryx2(
                    &config,
                    stage_config,
                    cycles_per_round,
                    args.observers,
                    Wakeup::Doorbell,
                )?,
                "iceoryx2-events" => {
                    run_iceoryx2(&config, stage_config, cycles_per_round, args.observers, Wakeup::Event)?
                }
                "iceoryx2-sem" => run_semaphore(&config, stage_config, cycles_per_round, args.observers)?,
                "udp" => run_udp(&config, stage_config, cycles_per_round, args.observers)?,
                _ => run_calls(&config, cycles_per_round)?,
            };
            results.absorb(round);
        }
    }
    let steered = reservation.interrupts.as_ref().map(|i| (i.moved(), i.kept_by_kernel));
    report(&mut all, args.duration, rounds, args.observers, steered, &config)
}

fn report(
    all: &mut [Results],
    duration: f64,
    rounds: usize,
    observers: usize,
    steered: Option<(usize, usize)>,
    config: &Config,
) -> Result<()> {
    let timing = &config.timing;
    let placed = match timing.loop_cpu {
        Some(cpu) => format!("loop on CPU {cpu}"),
        None => "loop unpinned".to_owned(),
    };
    let priority = match timing.realtime_priority {
        Some(p) => format!("SCHED_FIFO {p}"),
        None => "normal priority".to_owned(),
    };
    let idle = match timing.cpu_dma_latency_us {
        Some(us) => format!("CPU idle exit latency ≤ {us} µs"),
        None => "CPU idle states unlimited".to_owned(),
    };
    let interrupts = match steered {
        Some((moved, kept)) => format!(", {moved} device interrupts steered off it ({kept} kept there by the kernel)"),
        None => String::new(),
    };
    let mut text = format!(
        "bench latency: sensor reading → valve command through 5 stages, {} Hz, {duration} s per transport in {rounds} rounds taking turns; {observers} observers per service; {placed}{interrupts}, {priority}, {idle}\n\n{:<16} {:>9} {:>9} {:>9} {:>9} {:>12}\n",
        timing.control_rate_hz, "transport", "p50 µs", "p99 µs", "p99.9 µs", "max µs", "misses >1ms"
    );
    for r in all.iter_mut() {
        r.total.sort_unstable();
        text += &format!(
            "{:<16} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>12}\n",
            r.name,
            quantile_us(&r.total, 0.5),
            quantile_us(&r.total, 0.99),
            quantile_us(&r.total, 0.999),
            quantile_us(&r.total, 1.0),
            r.misses
        );
    }
    let find = |name: &str| all.iter().find(|r| r.name == name);
    text += "\n";
    for (over, under) in [
        ("iceoryx2", "udp"),
        ("iceoryx2-events", "udp"),
        ("iceoryx2-sem", "udp"),
        ("iceoryx2", "calls"),
    ] {
        if let (Some(a), Some(b)) = (find(over), find(under)) {
            text += &format!(
                "{over} / {under}: p50 {:.2}, p99 {:.2}\n",
                quantile_us(&a.total, 0.5) / quantile_us(&b.total, 0.5),
                quantile_us(&a.total, 0.99) / quantile_us(&b.total, 0.99)
            );
        }
    }
    text += "\nper hop, p50 / p99 µs (driver → sensor → friction → position → torque → valve → driver):\n";
    for r in all.iter_mut() {
        let hops: Vec<String> = r
            .hops
            .iter_mut()
            .map(|h| {
                h.sort_unstable();
                format!("{:.1}/{:.1}", quantile_us(h, 0.5), quantile_us(h, 0.99))
            })
            .collect();
        text += &format!("{:<16} {}\n", r.name, hops.join("  "));
    }
    text += "\nslowest cycles, end-to-end = per hop µs:\n";
    for r in all.iter() {
        for (total, hops) in r.slowest.iter() {
            let hops: Vec<String> = hops.iter().map(|h| format!("{:.1}", *h as f64 / 1000.0)).collect();
            text += &format!("{:<16} {:.1} = {}\n", r.name, *total as f64 / 1000.0, hops.join(" + "));
        }
    }
    crate::emit(&text)
}

fn spawn_stage(
    index: usize,
    transport: &str,
    udp_ports: Option<(u16, &[u16])>,
    scope: Option<&RunScope>,
    config: Option<&Path>,
) -> Result<Child> {
    let mut command = Command::new(std::env::current_exe()?);
    command
        .args(["bench-stage", "--index", &index.to_string(), "--transport", transport])
        .stdin(Stdio::null())
        .stdout(Stdio::piped());
    if let Some(config) = config {
        command.arg("--config").arg(config);
    }
    if let Some((next, observers)) = udp_ports {
        command.args(["--next-port", &next.to_string()]);
        if !observers.is_empty() {
            let ports: Vec<String> = observers.iter().map(u16::to_string).collect();
            command.args(["--observer-ports", &ports.join(",")]);
        }
    }
    if let Some(scope) = scope {
        command.env(PREFIX_ENV, scope.prefix());
    }
    command.spawn().context("starting a bench stage")
}

/// Loopback addresses of `ports`, resolved once, off the timed path.
fn udp_addresses(ports: &[u16]) -> Vec<std::net::SocketAddr> {
    ports
        .iter()
        .map(|port| std::net::SocketAddr::from(([127, 0, 0, 1], *port)))
        .collect()
}

/// Waits for a stage's "ready" line (UDP stages print their port on it).
fn ready_line(child: &mut Child) -> Result<String> {
    let stdout = child.stdout.take().context("stage stdout")?;
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line)?;
    if line.is_empty() {
        bail!("a bench stage exited before it was ready");
    }
    Ok(line.trim().to_owned())
}

/// The benchmark's stage processes: killed when dropped, so an early
/// return never leaves one running.
pub(crate) struct StageProcesses(Vec<Child>);

impl StageProcesses {
    /// Starts the five stages over a shared-memory `transport` in `scope`,
    /// each ready (its ports open) before the next starts.
    pub(crate) fn start_in(scope: &RunScope, transport: &str, stage_config: Option<&Path>) -> Result<Self> {
        let mut children = StageProcesses(Vec::new());
        for index in 0..5 {
            children
                .0
                .push(spawn_stage(index, transport, None, Some(scope), stage_config)?);
            if let Some(child) = children.0.last_mut() {
                ready_line(child)?;
            }
        }
        Ok(children)
    }

    pub(crate) fn pids(&self) -> Vec<u32> {
        self.0.iter().map(Child::id).collect()
    }
}

impl Drop for StageProcesses {
    fn drop(&mut self) {
        for child in self.0.iter_mut() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

fn run_iceoryx2(
    config: &Config,
    stage_config: Option<&Path>,
    cycles: u64,
    observers: usize,
    wakeup: Wakeup,
) -> Result<Results> {
    let name = match wakeup {
        Wakeup::Doorbell => "iceoryx2",
        Wakeup::Event => "iceoryx2-events",
    };
    let scope = RunScope::new(&format!("hbench{}_", std::process::id() % 100_000))?;
    scope.remove_all_files()?;
    let result = (|| -> Result<Results> {
        let bus = Bus::open(&scope, "bench-driver")?;
        let first: Outlet<BenchSample> = Outlet::open_waking(&bus, SERVICES[0], wakeup)?;
        let last: Inlet<BenchSample> = Inlet::open_waking(&bus, SERVICES[5], 4, wakeup)?;
        let observers = (0..observers)
            .flat_map(|_| SERVICES.map(|name| Reader::<BenchSample>::open(&bus, name, 4)))
            .collect::<Result<Vec<_>, _>>()?;
        let children = StageProcesses::start_in(&scope, name, stage_config)?;
        let results = drive(
            cycles,
            name,
            config,
            |s| round_trip(&first, &last, s, Duration::from_millis(50)),
            || {
                for observer in &observers {
                    observer.latest()?;
                }
                Ok(())
            },
        );
        drop(children);
        results
    })();
    let _ = scope.remove_dead_nodes();
    scope.remove_all_files()?;
    result
}

/// iceoryx2 with semaphore events: the driver sleeps in the semaphore's
/// blocking wait, so a helper thread wakes it should a round trip never
/// come back (its timed wait would poll).
fn run_semaphore(config: &Config, stage_config: Option<&Path>, cycles: u64, observers: usize) -> Result<Results> {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    use std::sync::Arc;
    const GIVE_UP: Duration = Duration::from_millis(50);
    let scope = RunScope::new(&format!("hbsem{}_", std::process::id() % 100_000))?;
    scope.remove_all_files()?;
    let result = (|| -> Result<Results> {
        let node = semaphore_service::open_node(&scope)?;
        let first: SemaphoreOutlet<BenchSample> = SemaphoreOutlet::open(&node, SERVICES[0])?;
        let last: SemaphoreInlet<BenchSample> = SemaphoreInlet::open(&node, SERVICES[5])?;
        let observers = (0..observers)
            .flat_map(|_| SERVICES.map(|name| SemaphoreReader::<BenchSample>::open(&node, name)))
            .collect::<Result<Vec<_>, _>>()?;
        let children = StageProcesses::start_in(&scope, "iceoryx2-sem", stage_config)?;
        let waiting_since_ns = Arc::new(AtomicU64::new(0));
        let done = Arc::new(AtomicBool::new(false));
        let watchdog = {
            let (waiting_since_ns, done, scope) = (waiting_since_ns.clone(), done.clone(), scope.clone());
            std::thread::spawn(move || -> Result<()> {
                let node = semaphore_service::open_node(&scope)?;
                let waker = SemaphoreWaker::open(&node, SERVICES[5])?;
                while !done.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(10));
                    let since = waiting_since_ns.load(Ordering::Relaxed);
                    if since != 0 && clock::now_ns().saturating_sub(since) > GIVE_UP.as_nanos() as u64 {
                        waker.wake()?;
                    }
                }
                Ok(())
            })
        };
        let results = drive(
            cycles,
            "iceoryx2-sem",
            config,
            |s| {
                first.publish(*s)?;
                let started = clock::now_ns();
                waiting_since_ns.store(started, Ordering::Relaxed);
                let answer = loop {
                    let mut answer = None;
                    while let Some(back) = last.next()? {
                        if back.seq == s.seq {
                            answer = Some(back);
                        }
                    }
                    if answer.is_some() || clock::now_ns().saturating_sub(started) > GIVE_UP.as_nanos() as u64 {
                        break answer;
                    }
                    last.wait()?;
                };
                waiting_since_ns.store(0, Ordering::Relaxed);
                Ok(answer)
            },
            || {
                for observer in &observers {
                    while observer.next()?.is_some() {}
                }
                Ok(())
            },
        );
        done.store(true, Ordering::Relaxed);
        drop(children);
        match watchdog.join() {
            Ok(outcome) => outcome?,
            Err(_) => anyhow::bail!("the benchmark's watchdog thread panicked"),
        }
        results
    })();
    // Semaphore nodes are not `ipc::Service` nodes: their files go by prefix.
    scope.remove_all_files()?;
    result
}

fn run_udp(config: &Config, stage_config: Option<&Path>, cycles: u64, observers: usize) -> Result<Results> {
    let back = UdpSocket::bind("127.0.0.1:0")?;
    back.set_read_timeout(Some(Duration::from_millis(50)))?;
    let mut next = back.local_addr()?.port();
    let observers = (0..observers)
        .map(|_| -> Result<UdpSocket> {
            let socket = UdpSocket::bind("127.0.0.1:0")?;
            socket.set_nonblocking(true)?;
            Ok(socket)
        })
        .collect::<Result<Vec<_>>>()?;
    let observer_ports = observers
        .iter()
        .map(|socket| Ok(socket.local_addr()?.port()))
        .collect::<Result<Vec<u16>>>()?;
    let mut children = StageProcesses(Vec::new());
    // Last stage first: each needs the next hop's port.
    for index in (0..5).rev() {
        children.0.push(spawn_stage(
            index,
            "udp",
            Some((next, &observer_ports)),
            None,
            stage_config,
        )?);
        if let Some(child) = children.0.last_mut() {
            next = ready_line(child)?.parse().context("a UDP stage's port")?;
        }
    }
    let out = UdpSocket::bind("127.0.0.1:0")?;
    out.connect(("127.0.0.1", next))?;
    let observer_addresses = udp_addresses(&observer_ports);
    let results = drive(
        cycles,
        "udp",
        config,
        |s| {
            let bytes = s.to_bytes();
            out.send(&bytes)?;
            for observer in &observer_addresses {
                out.send_to(&bytes, observer)?;
            }
            let mut buf = [0u8; BenchSample::WIRE_SIZE];
            loop {
                match back.recv(&mut buf) {
                    Ok(n) if n == BenchSample::WIRE_SIZE => {
                        let sample = BenchSample::from_bytes(&buf);
                        if sample.seq == s.seq {
                            return Ok(Some(sample));
                        }
                    }
                    Ok(_) => {}
                    Err(_) => return Ok(None),
                }
            }
        },
        || {
            let mut buf = [0u8; BenchSample::WIRE_SIZE];
            for observer in &observers {
                loop {
                    match observer.recv(&mut buf) {
                        Ok(_) => {}
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                        Err(e) => return Err(e.into()),
                    }
                }
            }
            Ok(())
        },
    );
    drop(children);
    results
}

fn run_calls(config: &Config, cycles: u64) -> Result<Results> {
    let mut stages: Vec<Stage> = (0..5).map(|i| Stage::new(i, config)).collect::<Result<_>>()?;
    drive(
        cycles,
        "calls",
        config,
        |s| {
            let mut sample = *s;
            for (i, stage) in stages.iter_mut().enumerate() {
                stage.apply(&mut sample);
                sample.stamps_ns[i + 1] = clock::now_ns();
            }
            Ok(Some(sample))
        },
        || Ok(()),
    )
}

/// Readings sent before the timed ones, for every stage to open its ports
/// and settle.
pub(crate) const SETTLE_CYCLES: u64 = 200;

/// Sends one reading per millisecond (paced, as the plant does) and records
/// each answer's latency; `between_cycles` (the observers' reading) runs
/// once a cycle is timed, as the live stack's observers read on other CPUs.
pub(crate) fn drive(
    cycles: u64,
    name: &'static str,
    config: &Config,
    mut round_trip: impl FnMut(&BenchSample) -> Result<Option<BenchSample>>,
    mut between_cycles: impl FnMut() -> Result<()>,
) -> Result<Results> {
    let period = Duration::from_secs_f64(config.timing.control_period());
    let mut results = Results::new(name, cycles as usize);
    // Let every stage open its ports and settle.
    for seq in 0..SETTLE_CYCLES {
        round_trip(&reading(seq))?;
        between_cycles()?;
        std::thread::sleep(period);
    }
    let mut next = Instant::now();
    for seq in SETTLE_CYCLES..SETTLE_CYCLES + cycles {
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
        next += period;
        let sent = reading(seq);
        match round_trip(&sent)? {
            Some(back) => results.record(&back, clock::now_ns()),
            None => results.misses += 1,
        }
        between_cycles()?;
        if Instant::now() > next + period * 10 {
            next = Instant::now();
        }
    }
    Ok(results)
}
