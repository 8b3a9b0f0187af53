//! What CPU this process runs on, from CPUID: the bench reports it (machines differ between
//! runs of the bench, and which path is fastest depends on the micro-architecture).

/// The CPU's vendor string (`GenuineIntel`, `AuthenticAMD`, ...), zeros off x86-64.
pub(crate) fn vendor() -> [u8; 12] {
    #[cfg(target_arch = "x86_64")]
    {
        let id = std::arch::x86_64::__cpuid(0);
        let mut v = [0u8; 12];
        v[..4].copy_from_slice(&id.ebx.to_le_bytes());
        v[4..8].copy_from_slice(&id.edx.to_le_bytes());
        v[8..].copy_from_slice(&id.ecx.to_le_bytes());
        v
    }
    #[cfg(not(target_arch = "x86_64"))]
    [0; 12]
}

/// The CPU's brand string (CPUID leaves `0x8000_0002..=0x8000_0004`, trimmed), `None` off
/// x86-64 or where the CPU has none.
fn brand() -> Option<String> {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::__cpuid;
        if __cpuid(0x8000_0000).eax < 0x8000_0004 {
            return None;
        }
        let bytes: Vec<u8> = (0x8000_0002u32..=0x8000_0004)
            .flat_map(|leaf| {
                let r = __cpuid(leaf);
                [r.eax, r.ebx, r.ecx, r.edx]
                    .into_iter()
                    .flat_map(u32::to_le_bytes)
            })
            .take_while(|&b| b != 0)
            .collect();
        let s = String::from_utf8_lossy(&bytes).trim().to_owned();
        (!s.is_empty()).then_some(s)
    }
    #[cfg(not(target_arch = "x86_64"))]
    None
}

/// The display family and model (CPUID leaf 1, with the extended fields where they apply), as
/// Linux's `/proc/cpuinfo` gives them.
#[cfg(target_arch = "x86_64")]
fn family_model() -> (u32, u32) {
    let eax = std::arch::x86_64::__cpuid(1).eax;
    let (base_family, base_model) = ((eax >> 8) & 0xF, (eax >> 4) & 0xF);
    let family = if base_family == 0xF {
        base_family + ((eax >> 20) & 0xFF)
    } else {
        base_family
    };
    let model = if base_family == 0x6 || base_family == 0xF {
        base_model | (((eax >> 16) & 0xF) << 4)
    } else {
        base_model
    };
    (family, model)
}

/// The CPU for reports: brand, vendor, family and model, e.g. `AMD EPYC (AuthenticAMD, family
/// 25 model 17)`; `unknown` off x86-64.
pub(crate) fn description() -> String {
    #[cfg(target_arch = "x86_64")]
    {
        let vendor = vendor();
        let vendor = String::from_utf8_lossy(&vendor);
        let (family, model) = family_model();
        let brand = brand().unwrap_or_else(|| "unnamed CPU".into());
        format!("{brand} ({vendor}, family {family} model {model})")
    }
    #[cfg(not(target_arch = "x86_64"))]
    "unknown".into()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Linux's `/proc/cpuinfo` field `name` (of the first CPU), if there is one: an answer
    /// independent of our CPUID reads.
    fn cpuinfo(name: &str) -> Option<String> {
        let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
        let line = info
            .lines()
            .find(|l| l.split(':').next().is_some_and(|k| k.trim() == name))?;
        Some(line.split_once(':')?.1.trim().to_owned())
    }

    #[test]
    fn vendor_brand_family_and_model_are_the_ones_linux_reports() {
        #[cfg(target_arch = "x86_64")]
        {
            if let Some(v) = cpuinfo("vendor_id") {
                assert_eq!(std::str::from_utf8(&vendor()).unwrap(), v);
            }
            if let (Some(f), Some(m)) = (cpuinfo("cpu family"), cpuinfo("model")) {
                assert_eq!(family_model(), (f.parse().unwrap(), m.parse().unwrap()));
            }
            if let (Some(name), Some(b)) = (cpuinfo("model name"), brand()) {
                // Linux trims the same string (and may squeeze its inner spaces).
                let squeeze = |s: &str| s.split_whitespace().collect::<Vec<_>>().join(" ");
                assert_eq!(squeeze(&b), squeeze(&name));
            }
            let d = description();
            assert!(d.contains("family") && d.contains(std::str::from_utf8(&vendor()).unwrap()));
        }
    }
}
