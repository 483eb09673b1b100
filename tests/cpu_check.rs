//! The start-up check that the CPU has the instruction sets the build uses
//! (`mpmcg::driver::cpu`) must itself run on a CPU that lacks some of them. The case it
//! is for is a build on a CPU with AVX-512 run on one without (most clusters' login and
//! compute nodes are all AVX2 or newer): `main`, the check and what it calls before the
//! library runs may use no AVX-512 instruction. The compiler is free to use the build's
//! sets anywhere, so this reads the machine code of this build's binary: no instruction
//! with an EVEX prefix (byte 0x62 first, which in 64-bit mode is always EVEX). VEX (AVX,
//! AVX2) is allowed: with AVX enabled, every SSE operation is VEX-encoded, so the check
//! cannot help a CPU without AVX (none made since 2011 for servers).

#[cfg(target_arch = "x86_64")]
#[test]
fn the_cpu_check_needs_no_avx512() {
    let bin = env!("CARGO_BIN_EXE_mpmcg");
    let out = match std::process::Command::new("objdump")
        .args(["-d", bin])
        .output()
    {
        Ok(o) if o.status.success() => o,
        // binutils is installed by scripts/setup.sh; say so if it is missing.
        other => panic!("objdump (binutils) is needed to read the binary: {other:?}"),
    };
    let text = String::from_utf8_lossy(&out.stdout);
    // Functions by mangled name: `mpmcg::main`, the check, and the rank test before
    // the message (`launcher_rank` if not inlined) (their helpers are inlined or in std, which is built for x86-64).
    let wanted = [
        "_ZN5mpmcg4main",
        "missing_feature",
        "launched_as_other_rank",
        "launcher_rank",
        "os_saves",
    ];
    let mut seen = Vec::new();
    let mut current: Option<&str> = None;
    let mut bad = Vec::new();
    let mut instructions = 0;
    for line in text.lines() {
        if line.ends_with(">:") {
            current = wanted.iter().copied().find(|w| line.contains(w));
            seen.extend(current);
            continue;
        }
        // "  addr:\tbytes\tmnemonic operands"; a long instruction's further bytes
        // follow on lines without a mnemonic.
        let mut fields = line.split('\t');
        if let (Some(w), Some(bytes), Some(insn)) = (current, fields.nth(1), fields.next()) {
            instructions += 1;
            if bytes.trim_start().starts_with("62 ") {
                bad.push(format!("{w}: {}", insn.trim()));
            }
        }
    }
    for w in [
        "_ZN5mpmcg4main",
        "missing_feature",
        "launched_as_other_rank",
    ] {
        assert!(seen.contains(&w), "no function `{w}` in {bin}");
    }
    assert!(instructions > 20, "read only {instructions} instructions");
    assert!(
        bad.is_empty(),
        "AVX-512 (EVEX) instructions in the start-up check:\n{}",
        bad.join("\n")
    );
}
