//! `cpu|gpu|auto`: which device a user asked for, and the GPU it opens.

use crate::context::{AdapterChoice, ContextOptions, GpuContext};
use crate::GpuError;

/// Where compute work runs, as users name it (`--device`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Device {
    /// The CPU.
    Cpu,
    /// The best GPU adapter there is, a software one (lavapipe) included; an error if there is
    /// none.
    Gpu,
    /// A hardware GPU if one is present and opens, else the CPU.
    Auto,
}

impl Device {
    pub const ALL: [Device; 3] = [Device::Cpu, Device::Gpu, Device::Auto];

    pub fn name(self) -> &'static str {
        match self {
            Device::Cpu => "cpu",
            Device::Gpu => "gpu",
            Device::Auto => "auto",
        }
    }

    pub fn parse(s: &str) -> Option<Device> {
        Device::ALL.into_iter().find(|d| d.name() == s)
    }
}

/// What [`open_device`] found: the GPU to use (`None`: the CPU) and a note for the user
/// (a software adapter, or `auto` falling back because a GPU would not open).
pub struct OpenedDevice {
    pub gpu: Option<GpuContext>,
    pub note: Option<String>,
}

/// Opens what `device` asks for. `Gpu` fails when no adapter exists at all; `Auto` falls
/// back to the CPU when there is no hardware GPU (quietly) or it cannot be opened (with a
/// note).
pub fn open_device(device: Device) -> Result<OpenedDevice, GpuError> {
    Ok(match device {
        Device::Cpu => OpenedDevice {
            gpu: None,
            note: None,
        },
        Device::Gpu => {
            let ctx = GpuContext::new(&ContextOptions::new(AdapterChoice::Any))?;
            let note = ctx.is_software().then(|| {
                format!(
                    "{} is a software adapter (the GPU emulated on the CPU): results are \
                     right, speed is not a GPU's",
                    ctx.adapter_name()
                )
            });
            OpenedDevice {
                gpu: Some(ctx),
                note,
            }
        }
        Device::Auto => match GpuContext::new(&ContextOptions::new(AdapterChoice::Hardware)) {
            Ok(ctx) => OpenedDevice {
                gpu: Some(ctx),
                note: None,
            },
            Err(GpuError::NoAdapter { .. }) => OpenedDevice {
                gpu: None,
                note: None,
            },
            Err(e) => OpenedDevice {
                gpu: None,
                note: Some(format!("using the CPU, the GPU could not be opened: {e}")),
            },
        },
    })
}

/// Keeps adapter probing quiet on headless machines. Mesa's Vulkan device-selection layer
/// connects to a Wayland display while adapters are enumerated, and without
/// `XDG_RUNTIME_DIR` libwayland prints an error for every attempt. The layer only reorders
/// adapters (sylva ranks them itself), so where no display can exist it is switched off,
/// unless the user steers it (`MESA_VK_DEVICE_SELECT*`, `NODEVICE_SELECT`).
///
/// Changes the process environment: call it at the start of `main`, before any thread.
pub fn quiet_headless_probing() {
    let set = |k: &str| std::env::var_os(k).is_some_and(|v| !v.is_empty());
    let steered = std::env::vars_os().any(|(k, _)| {
        k.to_string_lossy().starts_with("MESA_VK_DEVICE_SELECT") || k == "NODEVICE_SELECT"
    });
    if !set("XDG_RUNTIME_DIR") && !steered {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for d in Device::ALL {
            assert_eq!(Device::parse(d.name()), Some(d));
        }
        assert_eq!(Device::parse("tpu"), None);
    }

    #[test]
    fn cpu_opens_nothing_and_auto_never_fails() {
        let cpu = open_device(Device::Cpu).unwrap();
        assert!(cpu.gpu.is_none() && cpu.note.is_none());
        // Whatever this machine has, auto gives a hardware GPU or the CPU, never an error.
        let auto = open_device(Device::Auto).unwrap();
        if let Some(ctx) = &auto.gpu {
            assert!(!ctx.is_software());
        }
    }
}
