//! The memory budget (`--mem`): how much a run may hold resident.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// A number of bytes the run may keep resident at its peak.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct MemBudget(pub u64);

/// What the process itself holds before any grid work: code, allocator, the input shape
/// is counted separately by the stages.
pub const BASE_BYTES: u64 = 24 << 20;

/// Give the memory that earlier work freed back to the system, where the allocator
/// keeps it (free pages in the middle of the heap, which it hands back only from the
/// top). A stage calls it before it allocates its own state: the peak of a process that
/// ran another stage before (the voxelization, on MPI rank 0 or in `harmap run`) is
/// then that stage's own, not the sum of both.
pub fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages of the allocator's heaps.
    unsafe {
        libc::malloc_trim(0);
    }
}

impl MemBudget {
    /// Bytes available to grid work once the base overhead is taken off.
    #[must_use]
    pub fn work_bytes(self) -> u64 {
        self.0.saturating_sub(BASE_BYTES)
    }

    /// How many workers, each holding `per_worker` bytes, fit next to `fixed` bytes of
    /// shared state, capped at `threads`. Errors when not even one fits.
    pub fn workers(
        self,
        what: &str,
        fixed: u64,
        per_worker: u64,
        threads: usize,
    ) -> Result<usize, super::GridError> {
        let avail = self.work_bytes().saturating_sub(fixed);
        let n = avail / per_worker.max(1);
        if n == 0 {
            let need = BASE_BYTES + fixed + per_worker;
            return Err(super::GridError::Budget {
                budget: self.to_string(),
                what: what.to_owned(),
                needed: human(need),
                suggest: human(need.next_power_of_two()),
            });
        }
        Ok((n as usize).min(threads.max(1)))
    }
}

impl Default for MemBudget {
    fn default() -> Self {
        MemBudget(1 << 30)
    }
}

/// Bytes as a short human-readable size (`256MiB`, `1.5GiB`).
#[must_use]
pub fn human(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = bytes as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if (v - v.round()).abs() < 1e-9 {
        format!("{}{}", v.round() as u64, UNITS[u])
    } else {
        format!("{v:.1}{}", UNITS[u])
    }
}

impl fmt::Display for MemBudget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&human(self.0))
    }
}

impl FromStr for MemBudget {
    type Err = String;

    /// Parse `512MiB`, `1GiB`, `2G`, `300M`, `1048576` (bytes). Binary units throughout.
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        let split = t
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(t.len());
        let (num, unit) = t.split_at(split);
        let value: f64 = num
            .parse()
            .map_err(|_| format!("'{s}' is not a size; write it like 512MiB or 2GiB"))?;
        let mult: u64 = match unit.trim().to_ascii_lowercase().as_str() {
            "" | "b" => 1,
            "k" | "kb" | "kib" => 1 << 10,
            "m" | "mb" | "mib" => 1 << 20,
            "g" | "gb" | "gib" => 1 << 30,
            "t" | "tb" | "tib" => 1 << 40,
            other => {
                return Err(format!(
                    "unknown size unit '{other}' in '{s}'; use KiB, MiB, GiB or TiB"
                ))
            }
        };
        if !(value.is_finite() && value > 0.0) {
            return Err(format!("memory budget '{s}' must be positive"));
        }
        Ok(MemBudget((value * mult as f64) as u64))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_sizes() {
        assert_eq!("256MiB".parse::<MemBudget>().unwrap().0, 256 << 20);
        assert_eq!("1GiB".parse::<MemBudget>().unwrap().0, 1 << 30);
        assert_eq!("1.5G".parse::<MemBudget>().unwrap().0, 3 << 29);
        assert!("12 parsecs".parse::<MemBudget>().is_err());
        assert!("0MiB".parse::<MemBudget>().is_err());
        assert_eq!(human(256 << 20), "256MiB");
    }

    #[test]
    fn too_small_budget_names_the_need() {
        let e = MemBudget(1 << 20)
            .workers("a block", 0, 4 << 20, 2)
            .unwrap_err();
        assert!(e.to_string().contains("too small"), "{e}");
        assert_eq!(
            MemBudget(1 << 30)
                .workers("a block", 0, 1 << 20, 2)
                .unwrap(),
            2
        );
    }
}
