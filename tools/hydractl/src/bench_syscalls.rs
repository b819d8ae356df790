//! `hydractl bench syscalls`: the system calls each hop of the loop makes,
//! counted by `strace -c` attached to the five stages of `bench latency`'s
//! live-stack transport while they pass `--cycles` readings. A count, unlike
//! a latency, does not move with the machine's load: CI holds it to a
//! baseline (`tools/benches/guard.py`).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use hydractl_bus::{quiet_ipc_logging, Bus, Inlet, Outlet, RunScope, Wakeup};
use hydractl_config::Config;
use hydractl_samples::BenchSample;
use serde::Serialize;

use crate::bench_latency::{drive, round_trip, StageProcesses, SERVICES, STAGES};

#[derive(clap::Args)]
pub struct SyscallsArgs {
    /// Readings passed through the chain while counting (after 200 to
    /// settle, which are counted too).
    #[arg(long, default_value_t = 2000)]
    cycles: u64,
    /// The config whose stages run (default: the simulated default).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the counts as JSON.
    #[arg(long)]
    json: bool,
    /// `iceoryx2`: the live stack's (each hop woken by a doorbell);
    /// `iceoryx2-events`: woken by iceoryx2's datagram events.
    #[arg(long, default_value = "iceoryx2")]
    transport: String,
}

#[derive(Serialize)]
struct StageCalls {
    stage: &'static str,
    /// System calls per reading passed: the stage's wake-up, its work and
    /// the ring that wakes the next.
    per_cycle: f64,
    /// Each call's name and how many per reading.
    calls: Vec<(String, f64)>,
}

#[derive(Serialize)]
struct Report {
    transport: &'static str,
    cycles: u64,
    stages: Vec<StageCalls>,
}

/// `strace -c` attached to one process until it is told to stop.
struct Tracer {
    child: Child,
    output: PathBuf,
}

impl Tracer {
    fn attach(pid: u32, output: PathBuf) -> Result<Self> {
        let mut child = Command::new("strace")
            .args(["-c", "-f", "-o"])
            .arg(&output)
            .args(["-p", &pid.to_string()])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::NotFound => {
                    anyhow::anyhow!("bench syscalls needs strace, which is not installed (apt-get install strace)")
                }
                _ => anyhow::Error::new(e).context("starting strace"),
            })?;
        // strace says so on stderr once the process is attached.
        let stderr = child.stderr.take().context("strace's stderr")?;
        let mut line = String::new();
        BufReader::new(stderr)
            .read_line(&mut line)
            .context("reading strace's stderr")?;
        if !line.contains("attached") {
            let _ = child.kill();
            bail!(
                "strace could not attach to process {pid}: {} (it needs ptrace: root, or kernel.yama.ptrace_scope 0)",
                line.trim()
            );
        }
        Ok(Self { child, output })
    }

    /// Detaches and reads the summary: (name, calls) for each system call.
    fn finish(mut self) -> Result<Vec<(String, u64)>> {
        nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.child.id() as i32),
            nix::sys::signal::Signal::SIGINT,
        )
        .context("detaching strace")?;
        self.child.wait().context("waiting for strace")?;
        let text = std::fs::read_to_string(&self.output)
            .with_context(|| format!("reading strace's summary {}", self.output.display()))?;
        let _ = std::fs::remove_file(&self.output);
        Ok(parse_summary(&text))
    }
}

/// The rows of `strace -c`'s table: `% time seconds usecs/call calls
/// [errors] syscall`, without its total.
fn parse_summary(text: &str) -> Vec<(String, u64)> {
    text.lines()
        .filter_map(|line| {
            let fields: Vec<&str> = line.split_whitespace().collect();
            let name = *fields.last()?;
            let calls = fields.get(3)?.parse::<u64>().ok()?;
            (name != "total" && fields[0].parse::<f64>().is_ok()).then(|| (name.to_owned(), calls))
        })
        .collect()
}

pub fn bench(args: SyscallsArgs) -> Result<()> {
    quiet_ipc_logging();
    let config = Config::load_or_default(args.config.as_deref())?;
    let scope = RunScope::new(&format!("hbsys{}_", std::process::id() % 100_000))?;
    scope.remove_all_files()?;
    let (transport, wakeup) = match args.transport.as_str() {
        "iceoryx2" => ("iceoryx2", Wakeup::Doorbell),
        "iceoryx2-events" => ("iceoryx2-events", Wakeup::Event),
        other => bail!("--transport {other}: iceoryx2 or iceoryx2-events"),
    };
    let report = count(
        &config,
        args.config.as_deref(),
        args.cycles,
        &scope,
        (transport, wakeup),
    );
    scope.remove_all_files()?;
    let report = report?;
    if args.json {
        return crate::emit(&(serde_json::to_string_pretty(&report)? + "\n"));
    }
    let mut text = format!(
        "bench syscalls: system calls per reading of each stage ({} transport, strace -c over {} readings)\n",
        report.transport, report.cycles
    );
    for stage in &report.stages {
        let calls: Vec<String> = stage
            .calls
            .iter()
            .filter(|(_, n)| *n >= 0.005)
            .map(|(name, n)| format!("{name} {n:.2}"))
            .collect();
        text += &format!(
            "  {:<9} {:>5.2}  ({})\n",
            stage.stage,
            stage.per_cycle,
            calls.join(", ")
        );
    }
    crate::emit(&text)
}

fn count(
    config: &Config,
    stage_config: Option<&Path>,
    cycles: u64,
    scope: &RunScope,
    (transport, wakeup): (&'static str, Wakeup),
) -> Result<Report> {
    let bus = Bus::open(scope, "bench-driver")?;
    let first: Outlet<BenchSample> = Outlet::open_waking(&bus, SERVICES[0], wakeup)?;
    let last: Inlet<BenchSample> = Inlet::open_waking(&bus, SERVICES[5], 4, wakeup)?;
    let children = StageProcesses::start_in(scope, transport, stage_config)?;
    let tracers = children
        .pids()
        .iter()
        .enumerate()
        .map(|(i, pid)| {
            Tracer::attach(
                *pid,
                std::env::temp_dir().join(format!("hydractl-syscalls-{}-{i}", std::process::id())),
            )
        })
        .collect::<Result<Vec<_>>>()?;
    let settle_and_count = drive(
        cycles,
        transport,
        config,
        |s| round_trip(&first, &last, s, Duration::from_millis(200)),
        || Ok(()),
    )?;
    if settle_and_count.misses > cycles / 10 {
        bail!(
            "{} of {cycles} readings did not come back within 200 ms: the counts would be of a stalled chain",
            settle_and_count.misses
        );
    }
    // Every reading of the settling ones and the counted ones passed each stage.
    let passed = (cycles + crate::bench_latency::SETTLE_CYCLES) as f64;
    let mut stages = Vec::new();
    for (tracer, stage) in tracers.into_iter().zip(STAGES) {
        let calls = tracer.finish()?;
        let total: u64 = calls.iter().map(|(_, n)| n).sum();
        stages.push(StageCalls {
            stage,
            per_cycle: total as f64 / passed,
            calls: calls.into_iter().map(|(name, n)| (name, n as f64 / passed)).collect(),
        });
    }
    drop(children);
    Ok(Report {
        transport,
        cycles,
        stages,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strace_summaries_are_read_row_by_row_without_the_total() {
        let text = "% time     seconds  usecs/call     calls    errors syscall\n\
                    ------ ----------- ----------- --------- --------- ----------------\n \
                    99.96    0.012373           3      3977           futex\n  \
                    0.04    0.000005           5         1         1 restart_syscall\n\
                    ------ ----------- ----------- --------- --------- ----------------\n\
                    100.00    0.012378           3      3978         1 total\n";
        assert_eq!(
            parse_summary(text),
            [("futex".to_owned(), 3977), ("restart_syscall".to_owned(), 1)]
        );
    }
}
