//! What `weft bench` reports about the machine: the processor model, logical
//! CPUs, physical cores and SMT threads per core, and the process's peak
//! resident memory.

use std::collections::BTreeSet;
use std::path::Path;

use serde::Serialize;

/// The processor topology, as far as Linux tells it (`null` fields elsewhere).
#[derive(Clone, Debug, Serialize)]
pub struct Topology {
    /// `model name` from `/proc/cpuinfo`.
    pub model: Option<String>,
    /// Online logical CPUs (hardware threads) of the machine.
    pub logical_cpus: Option<usize>,
    /// Logical CPUs this process may run on (affinity, cgroup quota).
    pub available_cpus: usize,
    /// Distinct (package, core) pairs among the online logical CPUs.
    pub physical_cores: Option<usize>,
    pub sockets: Option<usize>,
    /// Logical CPUs per physical core (2 with SMT / hyper-threading on).
    pub threads_per_core: Option<usize>,
}

impl Topology {
    pub fn this() -> Self {
        let available_cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let model = cpuinfo_field(&cpuinfo, "model name")
            .or_else(|| cpuinfo_field(&cpuinfo, "Model"))
            .or_else(|| cpuinfo_field(&cpuinfo, "cpu model"));
        // (package, core) of every online logical CPU: sysfs first, then the
        // "physical id" / "core id" lines of /proc/cpuinfo.
        let pairs =
            sysfs_cores(Path::new("/sys/devices/system/cpu")).or_else(|| cpuinfo_cores(&cpuinfo));
        let (logical_cpus, physical_cores, sockets) = match &pairs {
            Some(p) => {
                let cores: BTreeSet<_> = p.iter().copied().collect();
                let packages: BTreeSet<_> = p.iter().map(|c| c.0).collect();
                (Some(p.len()), Some(cores.len()), Some(packages.len()))
            }
            None => {
                let n = cpuinfo
                    .lines()
                    .filter(|l| l.starts_with("processor"))
                    .count();
                ((n > 0).then_some(n), None, None)
            }
        };
        let threads_per_core = match (logical_cpus, physical_cores) {
            (Some(l), Some(c)) if c > 0 => Some(l.div_ceil(c)),
            _ => None,
        };
        Self {
            model,
            logical_cpus,
            available_cpus,
            physical_cores,
            sockets,
            threads_per_core,
        }
    }

    /// One line for the human report.
    pub fn describe(&self) -> String {
        let opt = |v: Option<usize>| v.map_or("?".to_string(), |n| n.to_string());
        format!(
            "{} — {} logical CPUs ({} available to this process), {} physical cores in {} \
             socket(s), {} thread(s) per core",
            self.model.as_deref().unwrap_or("unknown processor"),
            opt(self.logical_cpus),
            self.available_cpus,
            opt(self.physical_cores),
            opt(self.sockets),
            opt(self.threads_per_core),
        )
    }
}

fn cpuinfo_field(cpuinfo: &str, key: &str) -> Option<String> {
    cpuinfo.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        (k.trim() == key).then(|| v.trim().to_string())
    })
}

/// `(physical_package_id, core_id)` of each online CPU from sysfs.
fn sysfs_cores(root: &Path) -> Option<Vec<(i64, i64)>> {
    let online = std::fs::read_to_string(root.join("online")).ok()?;
    let cpus = parse_cpu_list(online.trim())?;
    let read = |cpu: usize, f: &str| -> Option<i64> {
        std::fs::read_to_string(root.join(format!("cpu{cpu}/topology/{f}")))
            .ok()?
            .trim()
            .parse()
            .ok()
    };
    let mut pairs = Vec::with_capacity(cpus.len());
    for cpu in cpus {
        pairs.push((read(cpu, "physical_package_id")?, read(cpu, "core_id")?));
    }
    (!pairs.is_empty()).then_some(pairs)
}

/// `(physical id, core id)` of each processor in /proc/cpuinfo.
fn cpuinfo_cores(cpuinfo: &str) -> Option<Vec<(i64, i64)>> {
    let mut pairs = Vec::new();
    for block in cpuinfo.split("\n\n").filter(|b| b.contains("processor")) {
        let package = cpuinfo_field(block, "physical id")?.parse().ok()?;
        let core = cpuinfo_field(block, "core id")?.parse().ok()?;
        pairs.push((package, core));
    }
    (!pairs.is_empty()).then_some(pairs)
}

/// A kernel CPU list such as `0-3,8,10-11`.
fn parse_cpu_list(s: &str) -> Option<Vec<usize>> {
    let mut out = Vec::new();
    for part in s.split(',').filter(|p| !p.is_empty()) {
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b): (usize, usize) = (a.parse().ok()?, b.parse().ok()?);
                out.extend(a..=b);
            }
            None => out.push(part.parse().ok()?),
        }
    }
    Some(out)
}

/// The process's peak resident set (`VmHWM` of `/proc/self/status`), bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line["VmHWM:".len()..]
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024)
}

/// Resets the peak resident set to the current one (Linux 4.0+), so a peak
/// read later is that of what ran since. Returns whether it worked.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_lists() {
        assert_eq!(
            parse_cpu_list("0-3,8,10-11"),
            Some(vec![0, 1, 2, 3, 8, 10, 11])
        );
        assert_eq!(parse_cpu_list("0"), Some(vec![0]));
        assert_eq!(parse_cpu_list("x"), None);
    }

    #[test]
    fn cpuinfo_pairs() {
        let text = "processor\t: 0\nmodel name\t: X\nphysical id\t: 0\ncore id\t: 0\n\n\
                    processor\t: 1\nmodel name\t: X\nphysical id\t: 0\ncore id\t: 0\n\n";
        assert_eq!(cpuinfo_cores(text), Some(vec![(0, 0), (0, 0)]));
        assert_eq!(cpuinfo_field(text, "model name").as_deref(), Some("X"));
    }
}
