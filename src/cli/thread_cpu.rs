//! A process's CPU time per group of threads, from /proc: which of the server's thread
//! pools (the global `rayon-N` workers, the backbone's `backbone-N`, tokio's workers,
//! ONNX Runtime's and the GPU driver's own) spends its CPU, without a profiler.

use std::collections::BTreeMap;

/// CPU seconds (user + system) so far of each thread group of process `pid`. A group is a
/// thread name without its trailing number (`rayon-3` → `rayon`); unnamed threads carry the
/// process's name. Threads that ended are not in it (the process's own total still counts
/// them). Empty where /proc cannot tell.
pub fn cpu_by_thread_group(pid: u32) -> BTreeMap<String, f64> {
    let mut out = BTreeMap::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return out };
    for task in tasks.flatten() {
        if let Some((name, seconds)) = std::fs::read_to_string(task.path().join("stat")).ok().as_deref().and_then(stat_cpu) {
            *out.entry(group_of(name).to_string()).or_insert(0.0) += seconds;
        }
    }
    out
}

/// A process's CPU time so far (user + system, its ended threads included), seconds; NaN
/// where /proc cannot tell.
pub fn process_cpu_seconds(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).ok().as_deref().and_then(stat_cpu).map_or(f64::NAN, |(_, s)| s)
}

/// The name and CPU seconds (utime + stime) of a /proc `stat` line. The name (field 2) may
/// hold spaces and parentheses: the fields are counted after its last closing parenthesis,
/// where utime and stime are the 12th and 13th.
fn stat_cpu(stat: &str) -> Option<(&str, f64)> {
    let (open, close) = (stat.find('(')?, stat.rfind(')')?);
    let fields: Vec<&str> = stat.get(close + 1..)?.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok());
    // SAFETY: sysconf only reads a constant of the running system.
    let per_second = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    Some((stat.get(open + 1..close)?, (ticks(11)? + ticks(12)?) / per_second))
}

/// A thread's group: its name without a trailing number and separator.
pub fn group_of(name: &str) -> &str {
    let stem = name.trim_end_matches(|c: char| c.is_ascii_digit());
    let stem = stem.trim_end_matches(['-', '_', ' ', ':', '#']);
    if stem.is_empty() {
        name
    } else {
        stem
    }
}

/// The growth of each group between two readings, largest first, as "group N ms" for the
/// `top` largest, each per `requests` requests.
pub fn describe_growth(before: &BTreeMap<String, f64>, after: &BTreeMap<String, f64>, requests: usize, top: usize) -> String {
    let mut grown: Vec<(&str, f64)> = after.iter().map(|(g, t)| (g.as_str(), t - before.get(g).copied().unwrap_or(0.0))).filter(|(_, d)| *d > 0.0).collect();
    grown.sort_by(|a, b| b.1.total_cmp(&a.1));
    let n = requests.max(1) as f64;
    grown.iter().take(top).map(|(g, d)| format!("{g} {:.0} ms", d * 1e3 / n)).collect::<Vec<_>>().join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_lines_give_name_and_cpu_seconds() {
        let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
        let line = "42 (rayon (x) 3) S 1 42 42 0 -1 4194304 100 0 0 0 250 50 0 0 20 0 1 0";
        let (name, seconds) = stat_cpu(line).unwrap();
        assert_eq!(name, "rayon (x) 3");
        assert!((seconds - 300.0 / hz).abs() < 1e-9, "{seconds}");
        assert!(stat_cpu("42 (cut").is_none() && stat_cpu("42 (short) S 1 2").is_none());
        assert!(process_cpu_seconds(std::process::id()) >= 0.0);
    }

    #[test]
    fn threads_group_by_name_without_their_number() {
        assert_eq!(group_of("rayon-12"), "rayon");
        assert_eq!(group_of("backbone-0"), "backbone");
        assert_eq!(group_of("tokio-runtime-w"), "tokio-runtime-w");
        assert_eq!(group_of("b2tf"), "b2tf");
        assert_eq!(group_of("1234"), "1234");
    }

    #[test]
    fn a_busy_named_thread_shows_in_its_group() {
        let pid = std::process::id();
        let before = cpu_by_thread_group(pid);
        let t = std::time::Instant::now();
        std::thread::Builder::new()
            .name("cpu-probe-7".into())
            .spawn(move || {
                let mut x = 0u64;
                while t.elapsed() < std::time::Duration::from_millis(300) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
                // Read while the thread still lives: /proc drops a thread's entry at its exit.
                cpu_by_thread_group(pid)
            })
            .unwrap()
            .join()
            .map(|after| {
                assert!(after.get("cpu-probe").copied().unwrap_or(0.0) > 0.05, "{after:?}");
                assert!(describe_growth(&before, &after, 1, 3).contains("cpu-probe"), "{}", describe_growth(&before, &after, 1, 3));
            })
            .unwrap();
    }
}
