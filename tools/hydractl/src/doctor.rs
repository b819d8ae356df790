//! `hydractl doctor`: whether this computer can hold the config's loop,
//! and what to change where it cannot. Every check reads the kernel's own
//! files (`/proc`, `/sys`, `/dev`), so that tests run it against fixture
//! trees of other machines (`--root`).

use std::path::{Path, PathBuf};

use anyhow::Result;
use hydractl_config::Config;
use hydractl_rt::CpuList;
use serde::Serialize;

#[derive(clap::Args)]
pub struct DoctorArgs {
    /// The config whose needs are checked [default: the built-in config/sim.toml].
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print JSON: {"checks": [{"name", "status", "detail", "fix"}], "ready"}.
    #[arg(long)]
    json: bool,
    /// Also measure the loop CPU's stalls for this many seconds, as `bench
    /// stalls` does, and judge them against the loop's period.
    #[arg(long, value_name = "SECONDS")]
    measure: Option<f64>,
    /// Read /proc, /sys and /dev under this folder instead of /: another
    /// machine's files, for tests.
    #[arg(long, hide = true)]
    root: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Pass,
    Warn,
    Fail,
}

#[derive(Debug, Clone, Serialize)]
pub struct Check {
    pub name: &'static str,
    pub status: Status,
    /// What was found.
    pub detail: String,
    /// What to change; empty when nothing is to be done.
    pub fix: String,
}

impl Check {
    fn pass(name: &'static str, detail: impl Into<String>) -> Self {
        Self {
            name,
            status: Status::Pass,
            detail: detail.into(),
            fix: String::new(),
        }
    }

    fn warn(name: &'static str, detail: impl Into<String>, fix: impl Into<String>) -> Self {
        Self {
            name,
            status: Status::Warn,
            detail: detail.into(),
            fix: fix.into(),
        }
    }

    fn fail(name: &'static str, detail: impl Into<String>, fix: impl Into<String>) -> Self {
        Self {
            name,
            status: Status::Fail,
            detail: detail.into(),
            fix: fix.into(),
        }
    }
}

#[derive(Serialize)]
struct Report {
    checks: Vec<Check>,
    ready: bool,
}

/// The machine's files, under `/` or a fixture's root.
pub struct Host {
    root: PathBuf,
}

impl Host {
    pub fn new(root: Option<PathBuf>) -> Self {
        Self {
            root: root.unwrap_or_else(|| PathBuf::from("/")),
        }
    }

    fn is_live(&self) -> bool {
        self.root == Path::new("/")
    }

    fn path(&self, absolute: &str) -> PathBuf {
        self.root.join(absolute.trim_start_matches('/'))
    }

    fn read(&self, absolute: &str) -> Option<String> {
        std::fs::read_to_string(self.path(absolute)).ok()
    }

    fn read_trimmed(&self, absolute: &str) -> Option<String> {
        self.read(absolute).map(|s| s.trim().to_owned())
    }

    /// A CAN interface's bit timing and state, as `ip -details -json link
    /// show` gives them: from `ip` itself on this machine, from
    /// `ip-link/IFACE.json` under a fixture's root.
    fn ip_link(&self, interface: &str) -> Option<String> {
        if self.is_live() {
            let out = std::process::Command::new("ip")
                .args(["-details", "-json", "link", "show", "dev", interface])
                .output()
                .ok()?;
            out.status
                .success()
                .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
        } else {
            self.read(&format!("ip-link/{interface}.json"))
        }
    }
}

pub fn doctor(args: DoctorArgs) -> Result<()> {
    let host = Host::new(args.root.clone());
    let mut checks = match Config::load_or_default(args.config.as_deref()) {
        Ok(config) => {
            let mut checks = run_checks(&host, &config);
            if let Some(seconds) = args.measure {
                checks.push(measure_stalls(&config, seconds));
            }
            checks
        }
        Err(e) => vec![Check::fail(
            "config",
            e.to_string(),
            "correct the config (every key is checked at load)",
        )],
    };
    checks.push(binaries());
    let ready = checks.iter().all(|c| c.status != Status::Fail);
    let report = Report { checks, ready };
    if args.json {
        crate::emit(&(serde_json::to_string_pretty(&report)? + "\n"))?;
    } else {
        crate::emit(&table(&report))?;
    }
    if !ready {
        // Said by the table; the exit status says it to a script.
        std::process::exit(1);
    }
    Ok(())
}

fn table(report: &Report) -> String {
    let mut text = format!("{:<16} {:<6} {}\n", "check", "status", "detail");
    for c in &report.checks {
        let status = match c.status {
            Status::Pass => "pass",
            Status::Warn => "warn",
            Status::Fail => "FAIL",
        };
        text += &format!("{:<16} {:<6} {}\n", c.name, status, c.detail);
        if !c.fix.is_empty() {
            text += &format!("{:<16} {:<6} fix: {}\n", "", "", c.fix);
        }
    }
    text += if report.ready {
        "ready: this computer can hold the config's loop\n"
    } else {
        "NOT ready: fix what failed above\n"
    };
    text
}

/// Every check of the computer against the config, in the order an
/// engineer would go through them.
pub fn run_checks(host: &Host, config: &Config) -> Vec<Check> {
    vec![
        preempt_rt(host),
        isolated_cpu(host, config.timing.loop_cpu),
        rtprio(host, config.timing.realtime_priority),
        memlock(host, config.timing.lock_memory),
        cpu_dma_latency(host, config.timing.loop_cpu, config.timing.cpu_dma_latency_us),
        governor(host, config.timing.loop_cpu),
        clocksource(host),
        swap(host),
        shm(host),
        can_interfaces(host, config),
        recording(config),
    ]
}

fn preempt_rt(host: &Host) -> Check {
    const NAME: &str = "preempt_rt";
    let version = host.read_trimmed("/proc/sys/kernel/version").unwrap_or_default();
    let realtime = host.read_trimmed("/sys/kernel/realtime").is_some_and(|v| v == "1");
    if realtime || version.contains("PREEMPT_RT") {
        Check::pass(NAME, format!("PREEMPT_RT kernel ({version})"))
    } else {
        Check::fail(
            NAME,
            format!("not a PREEMPT_RT kernel ({})", if version.is_empty() { "version unknown" } else { &version }),
            "boot a PREEMPT_RT kernel (mainline since 6.12, CONFIG_PREEMPT_RT=y; Debian: linux-image-rt-amd64 or -rt-arm64)",
        )
    }
}

/// The CPUs of a kernel CPU list (`1-3,5`); none when it is not one.
fn cpu_list(text: &str) -> Vec<usize> {
    CpuList::parse(text).map(|l| l.cpus().to_vec()).unwrap_or_default()
}

/// A `key=value` of the kernel's command line.
fn boot_parameter(cmdline: &str, key: &str) -> Option<String> {
    cmdline
        .split_ascii_whitespace()
        .find_map(|word| word.strip_prefix(key)?.strip_prefix('=').map(str::to_owned))
}

fn isolated_cpu(host: &Host, loop_cpu: Option<usize>) -> Check {
    const NAME: &str = "isolated_cpu";
    let Some(cpu) = loop_cpu else {
        return Check::warn(
            NAME,
            "the config pins the loop to no CPU ([timing] loop_cpu)",
            "set [timing] loop_cpu to a CPU reserved for the loop",
        );
    };
    let cmdline = host.read("/proc/cmdline").unwrap_or_default();
    let isolated = host
        .read("/sys/devices/system/cpu/isolated")
        .map(|t| cpu_list(&t))
        .unwrap_or_default();
    let nohz = host
        .read("/sys/devices/system/cpu/nohz_full")
        .map(|t| cpu_list(&t))
        .unwrap_or_default();
    let rcu_nocbs = boot_parameter(&cmdline, "rcu_nocbs")
        .map(|t| cpu_list(&t))
        .unwrap_or_default();
    let irqaffinity = boot_parameter(&cmdline, "irqaffinity").map(|t| cpu_list(&t));
    let mut missing = Vec::new();
    if !isolated.contains(&cpu) {
        missing.push("isolcpus");
    }
    if !nohz.contains(&cpu) {
        missing.push("nohz_full");
    }
    if !rcu_nocbs.contains(&cpu) {
        missing.push("rcu_nocbs");
    }
    if irqaffinity.as_ref().is_none_or(|cpus| cpus.contains(&cpu)) {
        missing.push("irqaffinity");
    }
    let fix = format!(
        "boot with isolcpus={cpu} nohz_full={cpu} rcu_nocbs={cpu} irqaffinity=<the other CPUs> (GRUB_CMDLINE_LINUX in /etc/default/grub, then update-grub)"
    );
    match missing.as_slice() {
        [] => Check::pass(
            NAME,
            format!("CPU {cpu} isolated, tickless, without RCU callbacks and interrupts"),
        ),
        m if m.contains(&"isolcpus") => Check::fail(
            NAME,
            format!(
                "the loop's CPU {cpu} is not isolated: the scheduler puts other work on it (missing: {})",
                m.join(", ")
            ),
            fix,
        ),
        m => Check::warn(NAME, format!("CPU {cpu} isolated, but without {}", m.join(", ")), fix),
    }
}

/// A soft limit from `/proc/self/limits`: `None` when unlimited.
fn soft_limit(limits: &str, name: &str) -> Option<Option<u64>> {
    let line = limits.lines().find(|l| l.starts_with(name))?;
    let soft = line[name.len()..].split_ascii_whitespace().next()?;
    Some(if soft == "unlimited" { None } else { soft.parse().ok() })
}

/// Whether capability `bit` is in the effective set of `/proc/self/status`.
fn has_capability(status: &str, bit: u32) -> bool {
    status
        .lines()
        .find_map(|l| l.strip_prefix("CapEff:"))
        .and_then(|hex| u64::from_str_radix(hex.trim(), 16).ok())
        .is_some_and(|caps| caps & (1 << bit) != 0)
}

const CAP_IPC_LOCK: u32 = 14;
const CAP_SYS_NICE: u32 = 23;

fn rtprio(host: &Host, priority: Option<u8>) -> Check {
    const NAME: &str = "rtprio";
    let Some(priority) = priority else {
        return Check::warn(
            NAME,
            "the config runs the loop at normal priority ([timing] realtime_priority)",
            "set [timing] realtime_priority (50: the valve runs one above)",
        );
    };
    // The valve runs one above the chain.
    let needed = u64::from(priority) + 1;
    let limits = host.read("/proc/self/limits").unwrap_or_default();
    let status = host.read("/proc/self/status").unwrap_or_default();
    let fix = format!("run as the hydractl service (LimitRTPRIO={needed} in its unit), or with CAP_SYS_NICE");
    if has_capability(&status, CAP_SYS_NICE) {
        return Check::pass(NAME, format!("SCHED_FIFO {needed} allowed (CAP_SYS_NICE)"));
    }
    match soft_limit(&limits, "Max realtime priority") {
        Some(None) => Check::pass(NAME, "SCHED_FIFO allowed at any priority (RLIMIT_RTPRIO unlimited)"),
        Some(Some(limit)) if limit >= needed => Check::pass(NAME, format!("SCHED_FIFO up to {limit} (needs {needed})")),
        Some(Some(limit)) => Check::fail(
            NAME,
            format!("SCHED_FIFO only up to {limit}, the loop needs {needed}"),
            fix,
        ),
        None => Check::fail(NAME, "RLIMIT_RTPRIO unknown (/proc/self/limits unreadable)", fix),
    }
}

fn memlock(host: &Host, lock_memory: bool) -> Check {
    const NAME: &str = "memlock";
    if !lock_memory {
        return Check::warn(
            NAME,
            "the config does not lock the loop's memory ([timing] lock_memory = false)",
            "set [timing] lock_memory = true",
        );
    }
    let limits = host.read("/proc/self/limits").unwrap_or_default();
    let status = host.read("/proc/self/status").unwrap_or_default();
    let fix = "LimitMEMLOCK=infinity in the unit (the package's sets it), or memlock unlimited in limits.conf";
    if has_capability(&status, CAP_IPC_LOCK) {
        return Check::pass(NAME, "memory can be locked (CAP_IPC_LOCK)");
    }
    match soft_limit(&limits, "Max locked memory") {
        Some(None) => Check::pass(NAME, "memory can be locked (RLIMIT_MEMLOCK unlimited)"),
        Some(Some(bytes)) => Check::fail(
            NAME,
            format!(
                "RLIMIT_MEMLOCK is {} kB: the loop processes cannot lock their memory",
                bytes / 1024
            ),
            fix,
        ),
        None => Check::fail(NAME, "RLIMIT_MEMLOCK unknown (/proc/self/limits unreadable)", fix),
    }
}

fn cpu_dma_latency(host: &Host, loop_cpu: Option<usize>, wanted_us: Option<u32>) -> Check {
    const NAME: &str = "cpu_dma_latency";
    let cpu = loop_cpu.unwrap_or(0);
    // The idle states the loop's CPU may enter, with their exit latencies.
    let idle = host.path(&format!("/sys/devices/system/cpu/cpu{cpu}/cpuidle"));
    let mut deepest_us = 0u64;
    if let Ok(states) = std::fs::read_dir(&idle) {
        for state in states.filter_map(Result::ok) {
            let latency = std::fs::read_to_string(state.path().join("latency"))
                .ok()
                .and_then(|t| t.trim().parse::<u64>().ok())
                .unwrap_or(0);
            let disabled = std::fs::read_to_string(state.path().join("disable")).is_ok_and(|t| t.trim() == "1");
            if !disabled {
                deepest_us = deepest_us.max(latency);
            }
        }
    }
    let device = host.path("/dev/cpu_dma_latency");
    let writable = device.exists() && nix::unistd::access(&device, nix::unistd::AccessFlags::W_OK).is_ok();
    let fix = "run the service as root for this, or give its group write access to /dev/cpu_dma_latency (the package's udev rule does)";
    match (writable, wanted_us) {
        (true, Some(us)) => Check::pass(
            NAME,
            format!("/dev/cpu_dma_latency writable: the run holds idle exit latency at {us} µs (deepest idle state {deepest_us} µs)"),
        ),
        (true, None) => Check::warn(
            NAME,
            format!("writable, but the config does not hold it: idle states up to {deepest_us} µs delay each wake-up"),
            "set [timing] cpu_dma_latency_us = 0",
        ),
        (false, _) if deepest_us <= 2 => Check::pass(
            NAME,
            format!("/dev/cpu_dma_latency not writable, but no idle state of CPU {cpu} is slower than {deepest_us} µs to leave"),
        ),
        (false, _) => Check::fail(
            NAME,
            format!("/dev/cpu_dma_latency not writable, and CPU {cpu} may sleep in idle states up to {deepest_us} µs deep"),
            fix,
        ),
    }
}

fn governor(host: &Host, loop_cpu: Option<usize>) -> Check {
    const NAME: &str = "governor";
    let cpu = loop_cpu.unwrap_or(0);
    match host.read_trimmed(&format!("/sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor")) {
        None => Check::pass(NAME, format!("CPU {cpu} has no frequency scaling (a fixed clock)")),
        Some(g) if g == "performance" => Check::pass(NAME, format!("CPU {cpu}: performance")),
        Some(g) => Check::warn(
            NAME,
            format!("CPU {cpu} scales its frequency ({g}): a cycle after idle runs slow"),
            format!("echo performance > /sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor (or cpupower frequency-set -g performance, at boot)"),
        ),
    }
}

fn clocksource(host: &Host) -> Check {
    const NAME: &str = "clocksource";
    let current = host
        .read_trimmed("/sys/devices/system/clocksource/clocksource0/current_clocksource")
        .unwrap_or_default();
    let available = host
        .read_trimmed("/sys/devices/system/clocksource/clocksource0/available_clocksource")
        .unwrap_or_default();
    match current.as_str() {
        "tsc" | "arch_sys_counter" | "kvm-clock" => Check::pass(NAME, format!("{current}: read without a system call")),
        "" => Check::warn(
            NAME,
            "the clock source is unknown",
            "check /sys/devices/system/clocksource",
        ),
        other => Check::warn(
            NAME,
            format!("{other} (available: {available}): every clock reading is slow"),
            "boot with clocksource=tsc (x86) and tsc=reliable if the kernel distrusts it",
        ),
    }
}

fn swap(host: &Host) -> Check {
    const NAME: &str = "swap";
    let swaps = host.read("/proc/swaps").unwrap_or_default();
    let devices: Vec<&str> = swaps
        .lines()
        .skip(1)
        .filter_map(|l| l.split_ascii_whitespace().next())
        .collect();
    if devices.is_empty() {
        Check::pass(NAME, "no swap")
    } else {
        Check::warn(
            NAME,
            format!(
                "swap on {}: the loop's memory is locked, but the processes beside it may stall on the disk",
                devices.join(", ")
            ),
            "swapoff -a, and remove the swap from /etc/fstab",
        )
    }
}

/// What a run's iceoryx2 segments take in /dev/shm, with room to spare
/// (measured: a run with a recorder about 30 MB).
const SHM_NEEDED_BYTES: u64 = 64 * 1024 * 1024;

fn shm(host: &Host) -> Check {
    const NAME: &str = "shm";
    let dir = host.path("/dev/shm");
    let free = nix::sys::statvfs::statvfs(&dir).ok().map(|s| free_bytes(&s));
    let stale = stale_ipc_files(host);
    match free {
        None => Check::fail(NAME, "/dev/shm is missing", "mount a tmpfs at /dev/shm"),
        Some(free) if free < SHM_NEEDED_BYTES => Check::fail(
            NAME,
            format!(
                "{} MB free in /dev/shm, a run needs about {} MB",
                free >> 20,
                SHM_NEEDED_BYTES >> 20
            ),
            "enlarge /dev/shm (size= of its tmpfs in /etc/fstab)",
        ),
        Some(free) if !stale.is_empty() => Check::warn(
            NAME,
            format!(
                "{} MB free; {} files of a run that is not alive (a killed run's), e.g. {}",
                free >> 20,
                stale.len(),
                stale[0]
            ),
            "hydractl run removes them as it starts; or remove them by hand",
        ),
        Some(free) => Check::pass(NAME, format!("{} MB free, no stale files", free >> 20)),
    }
}

/// Bytes an unprivileged process may still write on a file system.
// The block counts are 32 bits wide on some targets, 64 on others.
#[allow(clippy::unnecessary_cast)]
fn free_bytes(stat: &nix::sys::statvfs::Statvfs) -> u64 {
    stat.blocks_available() as u64 * stat.fragment_size() as u64
}

/// iceoryx2's files of the default prefix when no run of it is alive.
fn stale_ipc_files(host: &Host) -> Vec<String> {
    let prefix = std::env::var(hydractl_bus::PREFIX_ENV).unwrap_or_else(|_| hydractl_bus::DEFAULT_PREFIX.to_owned());
    if host.is_live() {
        let alive = hydractl_bus::RunScope::new(&prefix)
            .and_then(|scope| scope.live_node_names())
            .is_ok_and(|names| !names.is_empty());
        if alive {
            return Vec::new();
        }
    }
    // iceoryx2 keeps its node counter (`….global_mgmt`) and its empty
    // folders from run to run: not a killed run's.
    let segments = std::fs::read_dir(host.path("/dev/shm"))
        .into_iter()
        .flatten()
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with(&prefix) && !name.ends_with(".global_mgmt"));
    let mut stale: Vec<String> = segments.collect();
    let mut folders = vec![host.path("/tmp/iceoryx2").join(&prefix)];
    while let Some(folder) = folders.pop() {
        for entry in std::fs::read_dir(&folder).into_iter().flatten().filter_map(Result::ok) {
            match entry.file_type() {
                Ok(t) if t.is_dir() => folders.push(entry.path()),
                Ok(_) => stale.push(entry.path().display().to_string()),
                Err(_) => {}
            }
        }
    }
    stale
}

fn can_interfaces(host: &Host, config: &Config) -> Check {
    const NAME: &str = "can_interfaces";
    let Some(can) = &config.can else {
        return Check::pass(NAME, "the config names no CAN bus (the simulated plant)");
    };
    if can.transport != hydractl_can::profile::Transport::Socketcan {
        return Check::pass(NAME, "the config's CAN bus is the virtual one");
    }
    let (interface, bitrate) = match can.resolve() {
        Ok(profile) => (profile.interface.clone(), profile.bitrate),
        Err(e) => return Check::fail(NAME, e.to_string(), "correct [can] in the config"),
    };
    let sys = format!("/sys/class/net/{interface}");
    if !host.path(&sys).exists() {
        return Check::fail(
            NAME,
            format!("no interface {interface}"),
            format!("load the CAN adapter's driver (and can, can_raw), check its cable; `ip link show {interface}`"),
        );
    }
    // ARPHRD_CAN.
    if host.read_trimmed(&format!("{sys}/type")).is_some_and(|t| t != "280") {
        return Check::fail(
            NAME,
            format!("{interface} is not a CAN interface"),
            "name the CAN interface in [can] interface",
        );
    }
    let up_fix = format!("ip link set {interface} up type can bitrate {bitrate} (or a systemd-networkd .network with [CAN] BitRate={bitrate})");
    let flags = host
        .read_trimmed(&format!("{sys}/flags"))
        .and_then(|f| u32::from_str_radix(f.trim_start_matches("0x"), 16).ok())
        .unwrap_or(0);
    // IFF_UP.
    if flags & 0x1 == 0 {
        return Check::fail(NAME, format!("{interface} is down"), up_fix);
    }
    let Some(details) = host.ip_link(&interface).and_then(|json| can_details(&json)) else {
        return Check::warn(
            NAME,
            format!("{interface} is up; its bitrate and error state cannot be read (`ip -details -json link` failed)"),
            "install iproute2",
        );
    };
    if details.bitrate != Some(bitrate) {
        return Check::fail(
            NAME,
            format!(
                "{interface} runs at {} bit/s, the config's devices at {bitrate}",
                details.bitrate.map_or("an unknown".to_owned(), |b| b.to_string())
            ),
            up_fix,
        );
    }
    match details.state.as_deref() {
        Some("ERROR-ACTIVE") | None => Check::pass(NAME, format!("{interface} up at {bitrate} bit/s, error-active")),
        Some("ERROR-WARNING") => Check::warn(
            NAME,
            format!("{interface} up at {bitrate} bit/s, but ERROR-WARNING: errors on the bus"),
            "check the bus's termination and wiring",
        ),
        Some(state) => Check::fail(
            NAME,
            format!("{interface} up at {bitrate} bit/s, but {state}"),
            format!(
                "check the bus's termination and wiring; restart it: ip link set {interface} type can restart-ms 100"
            ),
        ),
    }
}

/// A CAN interface's bit rate and controller state, from `ip -details -json link show`.
#[derive(Debug, PartialEq)]
struct CanDetails {
    bitrate: Option<u32>,
    state: Option<String>,
}

fn can_details(json: &str) -> Option<CanDetails> {
    let links: serde_json::Value = serde_json::from_str(json).ok()?;
    let data = &links.get(0)?["linkinfo"]["info_data"];
    Some(CanDetails {
        bitrate: data["bittiming"]["bitrate"].as_u64().map(|b| b as u32),
        state: data["state"].as_str().map(str::to_owned),
    })
}

fn recording(config: &Config) -> Check {
    const NAME: &str = "recording";
    let r = &config.recording;
    let Some(out) = &r.out else {
        return Check::pass(NAME, "the config records no run ([recording] out)");
    };
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    // The folder, or the nearest one above it that exists (a run makes it).
    let existing = dir.ancestors().find(|d| d.exists()).unwrap_or(Path::new("/"));
    let Ok(stat) = nix::sys::statvfs::statvfs(existing) else {
        return Check::fail(
            NAME,
            format!("{} cannot be read", existing.display()),
            "create it, writable by the service's user",
        );
    };
    let free_mb = free_bytes(&stat) as f64 / 1e6;
    match r.keep_mb {
        None => Check::warn(
            NAME,
            format!(
                "records to {} without a limit: {free_mb:.0} MB free fill for certain",
                dir.display()
            ),
            "set [recording] keep_mb and split_duration_s: a ring of parts, the oldest deleted",
        ),
        Some(keep) if keep > free_mb => Check::fail(
            NAME,
            format!(
                "keep_mb = {keep} MB, but {} has {free_mb:.0} MB free: the disk fills before the ring turns",
                dir.display()
            ),
            format!("lower [recording] keep_mb below {free_mb:.0}, leaving room for the system"),
        ),
        Some(keep) => Check::pass(
            NAME,
            format!("a ring of {keep} MB in {}, {free_mb:.0} MB free", dir.display()),
        ),
    }
}

/// The process binaries the stack starts, where `hydractl run` finds them.
fn binaries() -> Check {
    const NAME: &str = "binaries";
    let dir = match hydractl_bus::process_dir() {
        Ok(dir) => dir,
        Err(e) => {
            return Check::fail(
                NAME,
                e.to_string(),
                "install the hydractl package, or set HYDRACTL_PROCESS_DIR",
            )
        }
    };
    let missing: Vec<&str> = hydractl_bus::PROCESS_BINARIES
        .iter()
        .filter(|name| nix::unistd::access(&dir.join(name), nix::unistd::AccessFlags::X_OK).is_err())
        .copied()
        .collect();
    if missing.is_empty() {
        Check::pass(NAME, format!("every process in {}", dir.display()))
    } else {
        Check::fail(
            NAME,
            format!("{} has no runnable {}", dir.display(), missing.join(", ")),
            "reinstall the hydractl package (or rebuild: cargo build --release --workspace)",
        )
    }
}

fn measure_stalls(config: &Config, seconds: f64) -> Check {
    const NAME: &str = "stalls";
    let period_ns = (1e9 / config.timing.control_rate_hz) as u64;
    match crate::bench_stalls::measure(config, config.timing.loop_cpu, seconds) {
        Err(e) => Check::fail(
            NAME,
            format!("{e:#}"),
            "run doctor --measure as root or as the service's user",
        ),
        Ok(s) => {
            let longest = s.longest_ns.first().copied().unwrap_or(0);
            let detail = format!(
                "longest stall {:.3} ms in {:.0} s (period {:.3} ms); {} ≥ 0.1 ms, {} ≥ 1 ms",
                longest as f64 / 1e6,
                s.spun_ns as f64 / 1e9,
                period_ns as f64 / 1e6,
                s.over[0],
                s.over[1]
            );
            let fix = "isolate the loop's CPU and boot PREEMPT_RT (the checks above); on a virtual machine, pin its virtual CPUs";
            if longest * 2 <= period_ns {
                Check::pass(NAME, detail)
            } else if longest < period_ns {
                Check::warn(NAME, detail + ": a stall takes more than half a period", fix)
            } else {
                Check::fail(NAME, detail + ": a stall longer than a period misses a deadline", fix)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_lists_and_boot_parameters_read_as_the_kernel_writes_them() {
        assert_eq!(cpu_list("1-3,5\n"), vec![1, 2, 3, 5]);
        assert_eq!(cpu_list("\n"), Vec::<usize>::new());
        let cmdline = "BOOT_IMAGE=/vmlinuz isolcpus=3 nohz_full=3 rcu_nocbs=3 irqaffinity=0-2 quiet";
        assert_eq!(boot_parameter(cmdline, "irqaffinity").as_deref(), Some("0-2"));
        assert_eq!(boot_parameter(cmdline, "rcu"), None);
    }

    #[test]
    fn limits_and_capabilities_read_as_proc_writes_them() {
        let limits = "Limit                     Soft Limit           Hard Limit           Units     \n\
                      Max locked memory         8388608              8388608              bytes     \n\
                      Max realtime priority     0                    0                    \n";
        assert_eq!(soft_limit(limits, "Max locked memory"), Some(Some(8_388_608)));
        assert_eq!(soft_limit(limits, "Max realtime priority"), Some(Some(0)));
        assert!(has_capability("CapEff:\t0000000000800000\n", CAP_SYS_NICE));
        assert!(!has_capability("CapEff:\t0000000000800000\n", CAP_IPC_LOCK));
    }

    #[test]
    fn the_bitrate_and_state_come_from_iproute2s_json() {
        // As `ip -details -json link show dev can0` prints it (iproute2 6.x).
        let json = r#"[{"ifindex":4,"ifname":"can0","flags":["NOARP","UP","LOWER_UP","ECHO"],"mtu":16,"qdisc":"pfifo_fast","operstate":"UP","linkmode":"DEFAULT","group":"default","txqlen":10,"link_type":"can","promiscuity":0,"min_mtu":0,"max_mtu":0,"linkinfo":{"info_kind":"can","info_data":{"ctrlmode":[],"state":"ERROR-ACTIVE","berr_counter":{"tx":0,"rx":0},"restart_ms":100,"bittiming":{"bitrate":1000000,"sample_point":"0.750","tq":25,"prop_seg":14,"phase_seg1":15,"phase_seg2":10,"sjw":1,"brp":2},"bittiming_const":{"name":"mcp251x","tseg1":{"min":3,"max":16},"tseg2":{"min":2,"max":8},"sjw":{"min":1,"max":4},"brp":{"min":1,"max":64},"brp_inc":1},"clock":8000000}},"num_tx_queues":1,"num_rx_queues":1}]"#;
        assert_eq!(
            can_details(json),
            Some(CanDetails {
                bitrate: Some(1_000_000),
                state: Some("ERROR-ACTIVE".into())
            })
        );
        assert_eq!(can_details("not json"), None);
    }
}
