//! Which adapters render on the CPU. wgpu reports lavapipe as `DeviceType::Cpu`, but a
//! coordinator only sees the adapter's name (`Capabilities::adapter`), so both are checked.

/// Lower-case fragments of the names software rasterisers report: Mesa's lavapipe (Vulkan) and
/// llvmpipe/softpipe (GL), Google's SwiftShader, Microsoft's WARP, Apple's software renderer.
const SOFTWARE_NAMES: &[&str] = &[
    "llvmpipe",
    "lavapipe",
    "softpipe",
    "swiftshader",
    "microsoft basic render driver",
    "software renderer",
    "software rasterizer",
];

/// True when an adapter called `name` (or whose device type the driver reports as a CPU,
/// `device_is_cpu`) renders in software.
pub fn is_software_rasteriser(name: &str, device_is_cpu: bool) -> bool {
    let name = name.to_ascii_lowercase();
    device_is_cpu || SOFTWARE_NAMES.iter().any(|s| name.contains(s))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn software_rasterisers_are_named() {
        // What lavapipe and llvmpipe report on Debian 12 (docs/platform.md).
        assert!(is_software_rasteriser(
            "llvmpipe (LLVM 15.0.6, 256 bits)",
            false
        ));
        assert!(is_software_rasteriser(
            "SwiftShader Device (Subzero)",
            false
        ));
        assert!(is_software_rasteriser(
            "Microsoft Basic Render Driver",
            false
        ));
        assert!(is_software_rasteriser("Some Unknown Device", true));
        assert!(!is_software_rasteriser("NVIDIA H200", false));
        assert!(!is_software_rasteriser(
            "AMD Radeon RX 7900 XTX (RADV NAVI31)",
            false
        ));
        assert!(!is_software_rasteriser(
            "Intel(R) Arc(tm) A770 Graphics (DG2)",
            false
        ));
        assert!(!is_software_rasteriser("", false));
    }
}
