//! Whether this CPU has the instruction sets the build uses. The build targets the
//! CPU that compiled it (`.cargo/config.toml`), so a binary copied to an older CPU
//! would die of SIGILL somewhere in a step; `mpmcg` checks first and says why.
//!
//! `std::arch::is_x86_feature_detected!` cannot tell: for a feature the build enables
//! it answers `true` at compile time. So the CPU is asked directly (CPUID), for the
//! sets a native build on a current x86-64 server enables.

#[cfg(target_arch = "x86_64")]
pub use x86::missing_feature;

#[cfg(target_arch = "x86_64")]
mod x86 {
    /// Where CPUID reports a set: leaf 1, leaf 7 (sub-leaf 0), leaf 7 sub-leaf 1, leaf
    /// 0x8000_0001; then the register (eax, ebx, ecx, edx) and the bit.
    const L1: usize = 0;
    const L7: usize = 1;
    const L71: usize = 2;
    const EXT: usize = 3;
    const EAX: usize = 0;
    const EBX: usize = 1;
    const ECX: usize = 2;
    const EDX: usize = 3;

    /// The table of instruction sets, once: [`missing_feature`] and, for the tests, each
    /// set with whether the build uses it and whether this CPU reports it, and what std
    /// detects at run time. The check is a chain of scalar tests, one CPUID per set the
    /// build uses (nothing else survives `cfg!`), no table in memory: nothing that needs
    /// AVX-512 (`tests/cpu_check.rs` reads the binary).
    macro_rules! feature_table {
        ($(($name:tt, $leaf:expr, $reg:expr, $bit:expr)),* $(,)?) => {
            /// The first instruction set the build uses that this CPU does not report, or
            /// whose registers the OS does not save (then so named).
            #[inline(never)]
            pub fn missing_feature() -> Option<&'static str> {
                $(
                    if cfg!(target_feature = $name) && (reg($leaf, $reg) >> $bit) & 1 == 0 {
                        return Some($name);
                    }
                )*
                // The AVX sets also need the OS to save their registers on a context switch
                // (XCR0: SSE and AVX state; AVX-512 adds the mask and upper-register state).
                if cfg!(target_feature = "avx") && !os_saves(0b110) {
                    return Some("avx (the OS does not enable its registers)");
                }
                if cfg!(target_feature = "avx512f") && !os_saves(0b1110_0110) {
                    return Some("avx512f (the OS does not enable its registers)");
                }
                None
            }

            #[cfg(test)]
            fn table() -> Vec<(&'static str, bool, bool)> {
                vec![$(($name, cfg!(target_feature = $name), (reg($leaf, $reg) >> $bit) & 1 == 1)),*]
            }

            #[cfg(test)]
            fn std_detects(name: &str) -> bool {
                match name {
                    $($name => std::arch::is_x86_feature_detected!($name),)*
                    _ => unreachable!("{name} is not in the table"),
                }
            }
        };
    }

    feature_table! {
        ("sse3", L1, ECX, 0),
        ("pclmulqdq", L1, ECX, 1),
        ("ssse3", L1, ECX, 9),
        ("fma", L1, ECX, 12),
        ("sse4.1", L1, ECX, 19),
        ("sse4.2", L1, ECX, 20),
        ("movbe", L1, ECX, 22),
        ("popcnt", L1, ECX, 23),
        ("aes", L1, ECX, 25),
        ("avx", L1, ECX, 28),
        ("f16c", L1, ECX, 29),
        ("bmi1", L7, EBX, 3),
        ("avx2", L7, EBX, 5),
        ("bmi2", L7, EBX, 8),
        ("avx512f", L7, EBX, 16),
        ("avx512dq", L7, EBX, 17),
        ("adx", L7, EBX, 19),
        ("avx512ifma", L7, EBX, 21),
        ("avx512cd", L7, EBX, 28),
        ("sha", L7, EBX, 29),
        ("avx512bw", L7, EBX, 30),
        ("avx512vl", L7, EBX, 31),
        ("avx512vbmi", L7, ECX, 1),
        ("avx512vbmi2", L7, ECX, 6),
        ("gfni", L7, ECX, 8),
        ("vaes", L7, ECX, 9),
        ("vpclmulqdq", L7, ECX, 10),
        ("avx512vnni", L7, ECX, 11),
        ("avx512bitalg", L7, ECX, 12),
        ("avx512vpopcntdq", L7, ECX, 14),
        ("avx512vp2intersect", L7, EDX, 8),
        ("avx512fp16", L7, EDX, 23),
        ("sha512", L71, EAX, 0),
        ("sm3", L71, EAX, 1),
        ("sm4", L71, EAX, 2),
        ("avxvnni", L71, EAX, 4),
        ("avx512bf16", L71, EAX, 5),
        ("avxifma", L71, EAX, 23),
        ("avxvnniint8", L71, EDX, 4),
        ("avxneconvert", L71, EDX, 5),
        ("avxvnniint16", L71, EDX, 10),
        ("lzcnt", EXT, ECX, 5),
        ("sse4a", EXT, ECX, 6),
    }

    /// Register `r` of CPUID leaf `leaf` (0 for a leaf the CPU lacks: a leaf above the
    /// highest it reports answers with another leaf's bits).
    fn reg(leaf: usize, r: usize) -> u32 {
        use std::arch::x86_64::{__cpuid, __cpuid_count};
        let (max, max_ext) = (__cpuid(0).eax, __cpuid(0x8000_0000).eax);
        let res = match leaf {
            L1 => __cpuid(1),
            L7 if max >= 7 => __cpuid_count(7, 0),
            L71 if max >= 7 => __cpuid_count(7, 1),
            EXT if max_ext >= 0x8000_0001 => __cpuid(0x8000_0001),
            _ => return 0,
        };
        match r {
            EAX => res.eax,
            EBX => res.ebx,
            ECX => res.ecx,
            _ => res.edx,
        }
    }

    /// Whether the OS has enabled every register state of `mask` in XCR0.
    fn os_saves(mask: u64) -> bool {
        // OSXSAVE: the OS manages the register states with XSAVE, and XGETBV may be used.
        if (reg(L1, ECX) >> 27) & 1 == 0 {
            return false;
        }
        // SAFETY: XGETBV executes when CPUID.1:ECX.OSXSAVE is set (checked above); register
        // 0 (XCR0) exists wherever XGETBV does.
        let xcr0 = unsafe { std::arch::x86_64::_xgetbv(0) };
        xcr0 & mask == mask
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        /// The tests run where the build was made, so it has every set the build uses.
        #[test]
        fn the_building_cpu_has_what_the_build_uses() {
            assert_eq!(missing_feature(), None);
        }

        /// Where the build does not use a set, `is_x86_feature_detected!` asks the CPU at
        /// run time: the table's leaf and bit must agree with it. std also asks the OS,
        /// which may disable the AVX sets (their registers need its support), and denies
        /// BMI1 and BMI2 on Intel CPUs without AVX (an erratum): there std may say no where
        /// CPUID says yes, never the other way. (With the native build few sets are left to
        /// ask; a build for `x86-64` asks all but SSE2's.)
        #[test]
        fn cpuid_bits_agree_with_std_where_std_asks_the_cpu() {
            let mut asked = 0;
            for (name, built, here) in table() {
                if built {
                    continue;
                }
                asked += 1;
                let std = std_detects(name);
                assert!(
                    !std || here,
                    "{name}: std detects it, its CPUID bit is clear"
                );
                if !name.starts_with("avx") && !matches!(name, "fma" | "f16c" | "bmi1" | "bmi2") {
                    assert_eq!(std, here, "{name}: std and its CPUID bit disagree");
                }
            }
            // No x86-64 CPU has every set of the table, so some are always asked.
            assert!(asked > 0);
        }
    }
}

/// Not x86-64: the build's target has no optional sets this checks.
#[cfg(not(target_arch = "x86_64"))]
pub fn missing_feature() -> Option<&'static str> {
    None
}
