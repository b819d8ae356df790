//! `hydractl doctor` against other machines' /proc, /sys and /dev: a
//! vehicle computer ready for the loop, a stock desktop kernel, and the
//! ready computer with its CAN adapter missing. Each tree holds the files
//! as those kernels write them.

use std::path::{Path, PathBuf};

use hydractl_system_tests::{hydractl, scratch_dir, ScratchDir};

fn vehicle_config() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/vehicle.toml")
}

/// Writes `files` (path under the root, contents) into a new root.
fn machine(name: &str, files: &[(&str, &str)]) -> ScratchDir {
    let root = scratch_dir(&format!("doctor-{name}"));
    for (path, text) in files {
        let path = root.join(path);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("folder");
        std::fs::write(&path, text).expect("file");
    }
    std::fs::create_dir_all(root.join("dev/shm")).expect("shm");
    root
}

const LIMITS_SERVICE: &str = "Limit                     Soft Limit           Hard Limit           Units     \n\
Max cpu time              unlimited            unlimited            seconds   \n\
Max locked memory         unlimited            unlimited            bytes     \n\
Max realtime priority     90                   90                   \n";

const LIMITS_DESKTOP: &str = "Limit                     Soft Limit           Hard Limit           Units     \n\
Max cpu time              unlimited            unlimited            seconds   \n\
Max locked memory         8388608              8388608              bytes     \n\
Max realtime priority     0                    0                    \n";

const STATUS_NO_CAPS: &str = "Name:\thydractl\nUmask:\t0022\nState:\tR (running)\nCapInh:\t0000000000000000\nCapPrm:\t0000000000000000\nCapEff:\t0000000000000000\n";

/// As `ip -details -json link show dev can0` prints an mcp251x adapter.
const CAN0_UP: &str = r#"[{"ifindex":4,"ifname":"can0","flags":["NOARP","UP","LOWER_UP","ECHO"],"mtu":16,"operstate":"UP","link_type":"can","linkinfo":{"info_kind":"can","info_data":{"ctrlmode":[],"state":"ERROR-ACTIVE","berr_counter":{"tx":0,"rx":0},"restart_ms":100,"bittiming":{"bitrate":1000000,"sample_point":"0.750","tq":25,"prop_seg":14,"phase_seg1":15,"phase_seg2":10,"sjw":1,"brp":2},"clock":8000000}}}]"#;

fn ready_files() -> Vec<(&'static str, &'static str)> {
    vec![
        (
            "proc/sys/kernel/version",
            "#1 SMP PREEMPT_RT Debian 6.12.43-1 (2025-08-27)\n",
        ),
        ("sys/kernel/realtime", "1\n"),
        (
            "proc/cmdline",
            "BOOT_IMAGE=/boot/vmlinuz-6.12.43+deb13-rt-amd64 root=/dev/mmcblk0p2 ro isolcpus=1 nohz_full=1 rcu_nocbs=1 irqaffinity=0,2-3 quiet\n",
        ),
        ("sys/devices/system/cpu/isolated", "1\n"),
        ("sys/devices/system/cpu/nohz_full", "1\n"),
        ("proc/self/limits", LIMITS_SERVICE),
        ("proc/self/status", STATUS_NO_CAPS),
        ("dev/cpu_dma_latency", ""),
        ("sys/devices/system/cpu/cpu1/cpuidle/state0/latency", "0\n"),
        ("sys/devices/system/cpu/cpu1/cpuidle/state1/latency", "2\n"),
        ("sys/devices/system/cpu/cpu1/cpuidle/state2/latency", "133\n"),
        ("sys/devices/system/cpu/cpu1/cpufreq/scaling_governor", "performance\n"),
        ("sys/devices/system/clocksource/clocksource0/current_clocksource", "tsc\n"),
        ("sys/devices/system/clocksource/clocksource0/available_clocksource", "tsc hpet acpi_pm \n"),
        ("proc/swaps", "Filename\t\t\t\tType\t\tSize\t\tUsed\t\tPriority\n"),
        ("sys/class/net/can0/type", "280\n"),
        ("sys/class/net/can0/flags", "0x40081\n"),
        ("sys/class/net/can0/operstate", "up\n"),
        ("ip-link/can0.json", CAN0_UP),
    ]
}

fn doctor(root: &Path) -> (Option<i32>, serde_json::Value) {
    let out = hydractl()
        .args(["doctor", "--json", "--config"])
        .arg(vehicle_config())
        .arg("--root")
        .arg(root)
        .output()
        .expect("doctor runs");
    let json =
        serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stderr)));
    (out.status.code(), json)
}

fn status_of<'a>(report: &'a serde_json::Value, name: &str) -> &'a str {
    report["checks"]
        .as_array()
        .expect("checks")
        .iter()
        .find(|c| c["name"] == name)
        .unwrap_or_else(|| panic!("no check {name}: {report}"))["status"]
        .as_str()
        .expect("status")
}

#[test]
fn a_vehicle_computer_set_up_for_the_loop_is_ready() {
    let root = machine("ready", &ready_files());
    let (code, report) = doctor(&root);
    for name in [
        "preempt_rt",
        "isolated_cpu",
        "rtprio",
        "memlock",
        "cpu_dma_latency",
        "governor",
        "clocksource",
        "swap",
        "shm",
        "can_interfaces",
        "binaries",
    ] {
        assert_eq!(status_of(&report, name), "pass", "{name}: {report}");
    }
    for check in report["checks"].as_array().expect("checks") {
        for key in ["name", "status", "detail", "fix"] {
            assert!(check[key].is_string(), "{key} in {check}");
        }
    }
    assert_eq!(report["ready"], true, "{report}");
    assert_eq!(code, Some(0));
}

#[test]
fn a_stock_desktop_kernel_is_not_ready_and_is_told_what_to_change() {
    let root = machine(
        "desktop",
        &[
            (
                "proc/sys/kernel/version",
                "#1 SMP PREEMPT_DYNAMIC Debian 6.12.43-1 (2025-08-27)\n",
            ),
            (
                "proc/cmdline",
                "BOOT_IMAGE=/boot/vmlinuz-6.12.43+deb13-amd64 root=UUID=0b1c ro quiet splash\n",
            ),
            ("sys/devices/system/cpu/isolated", "\n"),
            ("sys/devices/system/cpu/nohz_full", "(null)\n"),
            ("proc/self/limits", LIMITS_DESKTOP),
            ("proc/self/status", STATUS_NO_CAPS),
            ("sys/devices/system/cpu/cpu1/cpuidle/state0/latency", "0\n"),
            ("sys/devices/system/cpu/cpu1/cpuidle/state3/latency", "253\n"),
            ("sys/devices/system/cpu/cpu1/cpufreq/scaling_governor", "powersave\n"),
            ("sys/devices/system/clocksource/clocksource0/current_clocksource", "hpet\n"),
            ("sys/devices/system/clocksource/clocksource0/available_clocksource", "hpet acpi_pm \n"),
            (
                "proc/swaps",
                "Filename\t\t\t\tType\t\tSize\t\tUsed\t\tPriority\n/dev/nvme0n1p3                          partition\t16777212\t0\t\t-2\n",
            ),
            // A killed run's segment, beside iceoryx2's node counter, which
            // stays from run to run.
            ("dev/shm/hydractl_0354a209029e_1822247888.data", ""),
            ("dev/shm/hydractl_9204dd183d1c_node.0_10_0.global_mgmt", ""),
        ],
    );
    let (code, report) = doctor(&root);
    for (name, status) in [
        ("preempt_rt", "fail"),
        ("isolated_cpu", "fail"),
        ("rtprio", "fail"),
        ("memlock", "fail"),
        ("cpu_dma_latency", "fail"),
        ("governor", "warn"),
        ("clocksource", "warn"),
        ("swap", "warn"),
        ("shm", "warn"),
        ("can_interfaces", "fail"),
    ] {
        assert_eq!(status_of(&report, name), status, "{name}: {report}");
    }
    for check in report["checks"].as_array().expect("checks") {
        if check["status"] != "pass" {
            assert!(!check["fix"].as_str().unwrap_or("").is_empty(), "a fix for {check}");
        }
    }
    assert_eq!(report["ready"], false);
    assert_eq!(code, Some(1));
}

#[test]
fn a_missing_can_interface_fails_naming_it() {
    let files: Vec<_> = ready_files()
        .into_iter()
        .filter(|(path, _)| !path.contains("can0"))
        .collect();
    let root = machine("nocan", &files);
    let (code, report) = doctor(&root);
    assert_eq!(status_of(&report, "can_interfaces"), "fail", "{report}");
    let can = report["checks"]
        .as_array()
        .expect("checks")
        .iter()
        .find(|c| c["name"] == "can_interfaces")
        .expect("can check");
    assert!(can["detail"].as_str().is_some_and(|d| d.contains("can0")), "{can}");
    assert_eq!(status_of(&report, "preempt_rt"), "pass");
    assert_eq!(report["ready"], false);
    assert_eq!(code, Some(1));
}
