//! Where and how the live processes run. A wake-up across cores costs
//! about 25 µs per hop on a small virtual machine, so the loop's processes
//! share one CPU and everything else stays off it; at a real-time priority
//! no ordinary process delays them.
//!
//! What it holds: pinning a process to the loop's CPU or off it, real-time
//! priority, locked memory and a process's page faults, the kernel's CPU
//! lists (`CpuList`), and what a run reserves of the computer
//! (`reserve_for_run`: the CPUs' idle exit latency through the PM QoS
//! request, device interrupts steered off the loop's CPU, recorded in
//! `/run/hydractl-interrupts` until put back). No IPC: the bus is
//! `hydractl-bus`'s.

use nix::sched::{sched_setaffinity, CpuSet};
use nix::unistd::Pid;

/// Pins this process to the loop's CPU, when one is configured. A process
/// that cannot be pinned still runs, so callers report the error and go on.
pub fn pin_to_loop_cpu(loop_cpu: Option<usize>) -> Result<(), PlacementError> {
    match loop_cpu {
        Some(cpu) => pin(|set| set.set(cpu), format!("CPU {cpu}")),
        None => Ok(()),
    }
}

/// Keeps a process that is not in the loop (supervisor, monitor, tools)
/// off the loop's CPU, so it never delays a stage.
pub fn keep_off_loop_cpu(loop_cpu: Option<usize>) -> Result<(), PlacementError> {
    let Some(cpu) = loop_cpu else { return Ok(()) };
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    if cpus < 2 {
        return Ok(());
    }
    pin(
        |set| (0..cpus).filter(|&c| c != cpu).try_for_each(|c| set.set(c)),
        format!("the CPUs other than {cpu}"),
    )
}

/// Runs this process under SCHED_FIFO at `priority`, when one is
/// configured. Like pinning, a failure (no CAP_SYS_NICE) leaves the process
/// running, at normal priority, for the caller to report.
pub fn run_realtime(priority: Option<u8>) -> Result<(), PlacementError> {
    let Some(priority) = priority else { return Ok(()) };
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: plain system call on this process with a valid parameter.
    #[allow(unsafe_code)]
    let status = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if status == 0 {
        Ok(())
    } else {
        Err(PlacementError::Priority {
            priority,
            source: nix::Error::last(),
        })
    }
}

/// How much of the stack a loop touches before it locks its memory: a page
/// of the stack first reached on the loop would be a page fault there.
const STACK_TO_TOUCH: usize = 256 * 1024;

/// Locks every page of this process in memory, those it has and those it
/// will map (`mlockall`), and touches a stack's worth first, so that the
/// loop never waits for a page. Only with `RLIMIT_MEMLOCK` unlimited or as
/// root: with a finite limit, a later allocation past it would fail.
pub fn lock_memory() -> Result<(), PlacementError> {
    use nix::sys::resource::{getrlimit, Resource, RLIM_INFINITY};
    let (soft, _) = getrlimit(Resource::RLIMIT_MEMLOCK).map_err(|source| PlacementError::MemoryLock {
        reason: format!("cannot read RLIMIT_MEMLOCK: {source}"),
    })?;
    if soft != RLIM_INFINITY && !nix::unistd::geteuid().is_root() {
        return Err(PlacementError::MemoryLock {
            reason: format!(
                "its limit is {} kB (LimitMEMLOCK=infinity in the unit, or memlock unlimited in limits.conf)",
                soft / 1024
            ),
        });
    }
    touch_stack();
    nix::sys::mman::mlockall(nix::sys::mman::MlockAllFlags::MCL_CURRENT | nix::sys::mman::MlockAllFlags::MCL_FUTURE)
        .map_err(|source| PlacementError::MemoryLock {
            reason: source.to_string(),
        })
}

#[inline(never)]
fn touch_stack() {
    let mut stack = [0u8; STACK_TO_TOUCH];
    for page in stack.chunks_mut(4096) {
        page[0] = 1;
    }
    std::hint::black_box(&stack);
}

/// A process's page faults so far, minor and major (`/proc/PID/stat`
/// fields 10 and 12); `None` for this process's own.
pub fn page_faults(pid: Option<u32>) -> Option<u64> {
    let path = pid.map_or_else(|| "/proc/self/stat".to_owned(), |pid| format!("/proc/{pid}/stat"));
    let text = std::fs::read_to_string(path).ok()?;
    page_faults_in_stat(&text)
}

/// Whether process `pid` has memory locked (`VmLck` in `/proc/PID/status`).
pub fn memory_locked(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/status")).is_ok_and(|text| locked_kb(&text).is_some_and(|kb| kb > 0))
}

fn locked_kb(status: &str) -> Option<u64> {
    let line = status.lines().find_map(|l| l.strip_prefix("VmLck:"))?;
    line.split_ascii_whitespace().next()?.parse().ok()
}

fn page_faults_in_stat(text: &str) -> Option<u64> {
    // The command name, in parentheses, may hold spaces: count from after it.
    let (_, after_name) = text.rsplit_once(')')?;
    let fields: Vec<&str> = after_name.split_ascii_whitespace().collect();
    // Field 3 (the state) is the first after the name.
    let field = |n: usize| fields.get(n - 3)?.parse::<u64>().ok();
    Some(field(10)? + field(12)?)
}

/// The kernel's PM QoS request for the CPUs' wake-up latency.
const CPU_DMA_LATENCY: &str = "/dev/cpu_dma_latency";

/// A held limit on how slow a CPU may be to leave idle: while it lives, no
/// CPU enters an idle state whose exit latency exceeds the limit. The
/// kernel drops the request when the file closes, with the process or when
/// this is dropped.
#[derive(Debug)]
pub(crate) struct IdleLatencyLimit {
    _request: std::fs::File,
}

/// Asks the kernel to keep every CPU's idle exit latency at or below
/// `max_us` (the PM QoS interface that `cyclictest` uses). At 0 an idle CPU
/// polls instead of halting: on a virtual machine a halted virtual CPU is
/// woken through the host, about 25 µs per wake-up here, and the loop's
/// stages wake at every hop. The price is idle CPUs that draw power. Needs
/// root; like pinning, a failure leaves the run going, for the caller to
/// report.
pub(crate) fn limit_idle_latency(max_us: Option<u32>) -> Result<Option<IdleLatencyLimit>, PlacementError> {
    use std::io::Write;
    let Some(max_us) = max_us else { return Ok(None) };
    let request = || -> std::io::Result<std::fs::File> {
        let mut file = std::fs::OpenOptions::new().write(true).open(CPU_DMA_LATENCY)?;
        // The kernel takes the value as a binary 32-bit integer.
        file.write_all(&i32::try_from(max_us).unwrap_or(i32::MAX).to_ne_bytes())?;
        Ok(file)
    };
    request()
        .map(|file| Some(IdleLatencyLimit { _request: file }))
        .map_err(|source| PlacementError::IdleLatency { max_us, source })
}

/// Where the kernel lists device interrupts, one folder each.
const IRQ_DIR: &str = "/proc/irq";

/// The affinities the interrupts had before a run steered them, kept until
/// the run puts them back. In `/run`, which a reboot empties as it resets
/// the affinities, so that a run killed before it could put them back
/// leaves the next run what to put back.
pub const INTERRUPTS_RECORD: &str = "/run/hydractl-interrupts";

/// Device interrupts steered off the loop's CPU for the run: each one's
/// affinity as it was and as written. Dropping this puts back every one
/// still as written, and removes [`INTERRUPTS_RECORD`].
#[derive(Debug)]
pub struct SteeredInterrupts {
    moved: Vec<MovedInterrupt>,
    /// Interrupts the kernel would not move (managed ones, whose affinity
    /// the kernel itself spreads over the CPUs).
    pub kept_by_kernel: usize,
    record: std::path::PathBuf,
}

#[derive(Debug)]
struct MovedInterrupt {
    irq: String,
    was: String,
    written: String,
}

impl SteeredInterrupts {
    pub fn moved(&self) -> usize {
        self.moved.len()
    }
}

impl Drop for SteeredInterrupts {
    fn drop(&mut self) {
        for irq in &self.moved {
            let file = affinity_file(&irq.irq);
            let unchanged = std::fs::read_to_string(&file).is_ok_and(|now| now.trim() == irq.written);
            if unchanged {
                // Nothing to do with a failure here but leave the
                // interrupt where it is, off the loop's CPU.
                let _ = std::fs::write(&file, &irq.was);
            }
        }
        let _ = std::fs::remove_file(&self.record);
    }
}

fn affinity_file(irq: &str) -> std::path::PathBuf {
    std::path::Path::new(IRQ_DIR).join(irq).join("smp_affinity_list")
}

/// Moves every device interrupt that may run on `loop_cpu` to the other
/// CPUs it may run on, for as long as the returned value lives. An
/// interrupt's handler, and the softirq work that follows it, preempt even
/// a SCHED_FIFO stage: on this virtual machine, with the virtio devices'
/// interrupts free to land on the loop's CPU, a spinning SCHED_FIFO 99
/// loop there lost the CPU for 1 ms or more 9–10 times a minute, and 0–1
/// times with them moved (`hydractl bench stalls`). The permanent way on a
/// vehicle computer is the kernel's `irqaffinity=` and `isolcpus=`; this
/// is for a computer set up without them. Needs root; like pinning, a
/// failure leaves the run going, for the caller to report.
pub(crate) fn steer_interrupts_off(loop_cpu: Option<usize>) -> Result<Option<SteeredInterrupts>, PlacementError> {
    steer_interrupts_recorded_in(loop_cpu, std::path::Path::new(INTERRUPTS_RECORD))
}

fn steer_interrupts_recorded_in(
    loop_cpu: Option<usize>,
    record: &std::path::Path,
) -> Result<Option<SteeredInterrupts>, PlacementError> {
    let Some(cpu) = loop_cpu else { return Ok(None) };
    let refused = |source| PlacementError::Interrupts { cpu, source };
    // A run that was killed left its record: those are the affinities to
    // put back, not the steered ones it left.
    let recorded = match std::fs::read_to_string(record) {
        Ok(text) => parse_record(&text).map_err(|line| PlacementError::InterruptsRecord {
            path: record.to_owned(),
            line,
        })?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(refused(e)),
    };
    let mut irqs: Vec<String> = std::fs::read_dir(IRQ_DIR)
        .map_err(refused)?
        .filter_map(Result::ok)
        .map(|entry| entry.file_name().to_string_lossy().into_owned())
        .filter(|name| name.bytes().all(|b| b.is_ascii_digit()))
        .collect();
    irqs.sort();
    let mut plan = Vec::new();
    for irq in irqs {
        let Ok(now) = std::fs::read_to_string(affinity_file(&irq)) else {
            continue;
        };
        let now = now.trim().to_owned();
        let was = recorded
            .iter()
            .find(|(recorded_irq, _)| *recorded_irq == irq)
            .map_or(now.clone(), |(_, was)| was.clone());
        let Some(cpus) = CpuList::parse(&was).filter(|l| !l.is_empty()) else {
            continue;
        };
        let others = CpuList(cpus.cpus().iter().copied().filter(|&c| c != cpu).collect());
        if others.cpus().len() == cpus.cpus().len() || others.is_empty() {
            continue;
        }
        plan.push((irq, was, now, others.to_string()));
    }
    // The record first: should this process die half-way, the next run
    // still knows what to put back.
    let text: String = plan.iter().map(|(irq, was, _, _)| format!("{irq} {was}\n")).collect();
    std::fs::write(record, text).map_err(refused)?;
    let mut steered = SteeredInterrupts {
        moved: Vec::new(),
        kept_by_kernel: 0,
        record: record.to_owned(),
    };
    for (irq, was, now, written) in plan {
        let outcome = if now == written {
            Ok(())
        } else {
            std::fs::write(affinity_file(&irq), &written)
        };
        match outcome {
            Ok(()) => steered.moved.push(MovedInterrupt { irq, was, written }),
            // Not root: the file will not open for writing.
            Err(e) if e.raw_os_error() == Some(nix::errno::Errno::EACCES as i32) => return Err(refused(e)),
            // EPERM or EIO: a managed interrupt, placed by the kernel.
            Err(_) => steered.kept_by_kernel += 1,
        }
    }
    Ok(Some(steered))
}

/// The lines `IRQ CPU-LIST` of an interrupts record; the number of the
/// first line that is not one.
fn parse_record(text: &str) -> Result<Vec<(String, String)>, usize> {
    text.lines()
        .enumerate()
        .filter(|(_, line)| !line.trim().is_empty())
        .map(|(i, line)| {
            let mut fields = line.split_whitespace();
            match (fields.next(), fields.next(), fields.next()) {
                (Some(irq), Some(list), None)
                    if irq.bytes().all(|b| b.is_ascii_digit())
                        && CpuList::parse(list).is_some_and(|l| !l.is_empty()) =>
                {
                    Ok((irq.to_owned(), list.to_owned()))
                }
                _ => Err(i + 1),
            }
        })
        .collect()
}

/// A kernel CPU list, as `/proc`, `/sys` and the boot parameters write one
/// (`0-3,6`), and as `smp_affinity_list` takes one back (`0,1,2,3,6`).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct CpuList(Vec<usize>);

impl CpuList {
    /// The CPUs of `text` (surrounding white space ignored; an empty list is
    /// empty); `None` if it is not a CPU list.
    pub fn parse(text: &str) -> Option<CpuList> {
        let mut cpus = Vec::new();
        for part in text.trim().split(',').filter(|p| !p.is_empty()) {
            match part.split_once('-') {
                Some((first, last)) => cpus.extend(first.parse::<usize>().ok()?..=last.parse().ok()?),
                None => cpus.push(part.parse().ok()?),
            }
        }
        Some(CpuList(cpus))
    }

    pub fn cpus(&self) -> &[usize] {
        &self.0
    }

    pub fn contains(&self, cpu: usize) -> bool {
        self.0.contains(&cpu)
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl std::fmt::Display for CpuList {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = self.0.iter().map(usize::to_string).collect();
        f.write_str(&parts.join(","))
    }
}

/// What a run holds for its loop while it lasts: the idle-latency request
/// and the interrupts steered off the loop's CPU. Dropping it gives both
/// back.
#[derive(Debug)]
pub struct RunReservation {
    _idle_latency: Option<IdleLatencyLimit>,
    pub interrupts: Option<SteeredInterrupts>,
}

/// Takes what the config asks of the computer for a run (`hydractl run`'s
/// supervisor, and the latency benchmark alike); every failure is returned,
/// none stops it.
pub fn reserve_for_run(
    loop_cpu: Option<usize>,
    cpu_dma_latency_us: Option<u32>,
    interrupts_off_loop_cpu: bool,
) -> (RunReservation, Vec<PlacementError>) {
    let mut refusals = Vec::new();
    let idle_latency = limit_idle_latency(cpu_dma_latency_us).unwrap_or_else(|e| {
        refusals.push(e);
        None
    });
    let interrupts = if interrupts_off_loop_cpu {
        steer_interrupts_off(loop_cpu).unwrap_or_else(|e| {
            refusals.push(e);
            None
        })
    } else {
        None
    };
    (
        RunReservation {
            _idle_latency: idle_latency,
            interrupts,
        },
        refusals,
    )
}

/// Pins this loop process and raises its priority as `loop_cpu` and
/// `realtime_priority` say; every failure is returned, none stops it.
pub fn enter_loop(loop_cpu: Option<usize>, realtime_priority: Option<u8>) -> Vec<PlacementError> {
    [pin_to_loop_cpu(loop_cpu), run_realtime(realtime_priority)]
        .into_iter()
        .filter_map(Result::err)
        .collect()
}

#[derive(Debug, thiserror::Error)]
pub enum PlacementError {
    #[error("cannot pin to {what}: {source}; running unpinned")]
    Pin { what: String, source: nix::Error },
    #[error("cannot run at real-time priority {priority} (SCHED_FIFO needs root or CAP_SYS_NICE): {source}; running at normal priority")]
    Priority { priority: u8, source: nix::Error },
    #[error("cannot lock memory: {reason}; its pages may be faulted in on the loop")]
    MemoryLock { reason: String },
    #[error("cannot hold {CPU_DMA_LATENCY} at {max_us} µs (needs root): {source}; idle CPUs may sleep deeply and wake slowly")]
    IdleLatency { max_us: u32, source: std::io::Error },
    #[error("cannot steer device interrupts off CPU {cpu} through {IRQ_DIR} (needs root): {source}; their handlers may delay the loop")]
    Interrupts { cpu: usize, source: std::io::Error },
    #[error("{path}, line {line}: not `IRQ CPU-LIST`; interrupts left where they are (remove the file once they are where they belong)")]
    InterruptsRecord { path: std::path::PathBuf, line: usize },
}

fn pin(fill: impl FnOnce(&mut CpuSet) -> nix::Result<()>, what: String) -> Result<(), PlacementError> {
    let mut set = CpuSet::new();
    fill(&mut set)
        .and_then(|()| sched_setaffinity(Pid::from_raw(0), &set))
        .map_err(|source| PlacementError::Pin { what, source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn page_faults_are_read_past_a_command_name_with_spaces() {
        let stat = "4242 (a (b) c) S 1 4242 4242 0 -1 4194304 1234 0 56 0 10 2 0 0 20 0 1 0 100 1000 10";
        assert_eq!(page_faults_in_stat(stat), Some(1234 + 56));
        assert_eq!(page_faults_in_stat("4242 (x) S 1"), None);
        assert!(page_faults(None).is_some(), "this process's own");
        assert_eq!(
            locked_kb("Name:\tvalve\nVmLck:\t   12345 kB\nVmPin:\t0 kB\n"),
            Some(12345)
        );
        assert_eq!(locked_kb("Name:\tvalve\n"), None);
    }

    #[test]
    fn cpu_lists_read_and_write_as_the_kernel_does() {
        let cpus = |text: &str| CpuList::parse(text).map(|l| l.cpus().to_vec());
        assert_eq!(cpus("0-1"), Some(vec![0, 1]));
        assert_eq!(cpus("0,2-4,7"), Some(vec![0, 2, 3, 4, 7]));
        assert_eq!(cpus("3"), Some(vec![3]));
        assert_eq!(cpus("1-3,5\n"), Some(vec![1, 2, 3, 5]));
        assert_eq!(cpus("\n"), Some(vec![]));
        assert_eq!(cpus("0-x"), None);
        assert_eq!(CpuList(vec![0, 2, 3]).to_string(), "0,2,3");
        assert!(CpuList::parse("0-3,6").expect("list").contains(2));
    }

    #[test]
    fn an_interrupts_record_reads_back_or_names_its_bad_line() {
        assert_eq!(
            parse_record("24 0-1\n36 0,1\n"),
            Ok(vec![
                ("24".to_owned(), "0-1".to_owned()),
                ("36".to_owned(), "0,1".to_owned())
            ])
        );
        assert_eq!(parse_record(""), Ok(vec![]));
        assert_eq!(parse_record("24 0-1\n25 x\n"), Err(2));
        assert_eq!(parse_record("24 0-1 7\n"), Err(1));
    }

    #[test]
    fn a_bad_interrupts_record_is_an_error_naming_it() {
        let record = std::env::temp_dir().join(format!("hydractl-interrupts-test-{}", std::process::id()));
        std::fs::write(&record, "24 0-1\nnonsense\n").expect("writing the record");
        let e = steer_interrupts_recorded_in(Some(1), &record).expect_err("a bad record");
        std::fs::remove_file(&record).ok();
        let text = e.to_string();
        assert!(
            text.contains("hydractl-interrupts-test") && text.contains("line 2"),
            "{text}"
        );
    }

    #[test]
    fn no_loop_cpu_steers_no_interrupt() {
        assert!(matches!(steer_interrupts_off(None), Ok(None)));
    }

    #[test]
    fn no_idle_latency_limit_asks_nothing_of_the_kernel() {
        assert!(matches!(limit_idle_latency(None), Ok(None)));
    }

    #[test]
    fn an_idle_latency_limit_is_held_or_its_refusal_names_the_device() {
        match limit_idle_latency(Some(0)) {
            Ok(Some(_held)) => {
                // While held, the kernel's effective limit is at most ours.
                let effective = std::fs::read(CPU_DMA_LATENCY).expect("reading the request back");
                let bytes: [u8; 4] = effective[..4].try_into().expect("four bytes");
                assert_eq!(i32::from_ne_bytes(bytes), 0);
            }
            Ok(None) => panic!("a limit was asked for"),
            Err(e) => assert!(e.to_string().contains(CPU_DMA_LATENCY), "{e}"),
        }
    }
}
