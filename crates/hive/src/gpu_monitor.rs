//! GPU telemetry through NVML where an NVIDIA driver is present: utilisation,
//! memory and power of every GPU. NVML is loaded at run time, so the binary
//! needs no GPU; without one every reading is `None` and nothing fails.

use nvml_wrapper::Nvml;

/// One reading, summed or averaged over the machine's GPUs.
#[derive(Debug, Clone, Copy, Default)]
pub struct GpuReading {
    /// Mean utilisation (%).
    pub util_pct: f64,
    /// Memory in use (MB).
    pub mem_mb: f64,
    /// Total power draw (W).
    pub power_w: f64,
}

/// Reads NVML, if there is one.
pub struct GpuMonitor {
    nvml: Option<Nvml>,
}

impl GpuMonitor {
    /// Opens NVML; without an NVIDIA driver the monitor reports nothing.
    pub fn new() -> Self {
        let nvml = Nvml::init().ok().filter(|n| n.device_count().is_ok_and(|c| c > 0));
        Self { nvml }
    }

    /// True when NVML found at least one GPU.
    #[cfg(test)]
    pub fn present(&self) -> bool {
        self.nvml.is_some()
    }

    /// The current reading, or `None` without a GPU (or when NVML fails).
    pub fn read(&self) -> Option<GpuReading> {
        let nvml = self.nvml.as_ref()?;
        let count = nvml.device_count().ok()?;
        let mut r = GpuReading::default();
        for i in 0..count {
            let d = nvml.device_by_index(i).ok()?;
            r.util_pct += d.utilization_rates().ok()?.gpu as f64 / count as f64;
            r.mem_mb += d.memory_info().ok()?.used as f64 / 1e6;
            r.power_w += d.power_usage().map(|mw| mw as f64 / 1e3).unwrap_or(0.0);
        }
        Some(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reading_exists_exactly_when_a_gpu_was_found() {
        // On this machine (whatever it has) opening NVML never panics, and
        // a reading exists exactly when a GPU was found.
        let real = GpuMonitor::new();
        assert_eq!(real.read().is_some(), real.present());
    }
}
