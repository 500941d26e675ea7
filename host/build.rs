//! Which vector instructions the machine building the tests has, so that a test of a
//! kernel compiled for instructions this machine lacks is reported as ignored, not as
//! passed (the kernels themselves pick their copy at run time, `src/cpu.rs`; this is for
//! the tests only). Set only when the build is for the machine it runs on (host =
//! target); such a test run anyway (`--include-ignored`) on a machine without the
//! instructions fails rather than passing unrun.
//!
//! - `build_cpu_avx2`: AVX2 (the tactile and path kernels);
//! - `build_cpu_avx2_bmi`: AVX2 with BMI1/2, POPCNT and LZCNT (the stereo kernels);
//! - `build_cpu_avx512_popcnt`: that and AVX-512's byte population count (F, BW, VL,
//!   BITALG: the census costs' third copy).

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    for cfg in [
        "build_cpu_avx2",
        "build_cpu_avx2_bmi",
        "build_cpu_avx512_popcnt",
    ] {
        println!("cargo::rustc-check-cfg=cfg({cfg})");
    }
    let native = std::env::var("HOST").ok() == std::env::var("TARGET").ok();
    for cfg in if native { detected() } else { Vec::new() } {
        println!("cargo::rustc-cfg={cfg}");
    }
}

/// The cfgs this machine's CPU earns.
#[cfg(target_arch = "x86_64")]
fn detected() -> Vec<&'static str> {
    let mut cfgs = Vec::new();
    if std::is_x86_feature_detected!("avx2") {
        cfgs.push("build_cpu_avx2");
        if std::is_x86_feature_detected!("bmi1")
            && std::is_x86_feature_detected!("bmi2")
            && std::is_x86_feature_detected!("popcnt")
            && std::is_x86_feature_detected!("lzcnt")
        {
            cfgs.push("build_cpu_avx2_bmi");
            if std::is_x86_feature_detected!("avx512f")
                && std::is_x86_feature_detected!("avx512bw")
                && std::is_x86_feature_detected!("avx512vl")
                && std::is_x86_feature_detected!("avx512bitalg")
            {
                cfgs.push("build_cpu_avx512_popcnt");
            }
        }
    }
    cfgs
}

/// Other architectures have none of these kernels.
#[cfg(not(target_arch = "x86_64"))]
fn detected() -> Vec<&'static str> {
    Vec::new()
}
