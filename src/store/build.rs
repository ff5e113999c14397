//! Links HDF5 statically where the system provides its static archive (`libhdf5.a`, e.g.
//! Debian/Ubuntu's libhdf5-dev), so that the binaries stop loading the shared library and the
//! ~35 it pulls in (libcurl with its TLS, Kerberos and LDAP stack, for HDF5's S3 driver, which
//! imulab never uses): that loading and relocating cost every `imulab` process several ms
//! of CPU before `main` (docs/bench/allan.md, "whole process"). The archive's objects that
//! need curl are the S3 driver's alone, which nothing references, so the linker leaves them
//! out.
//!
//! hdf5-metno-sys still asks for the shared library; this archive comes earlier on the link
//! line (native libraries follow the crates that use them), resolves every HDF5 symbol, and
//! `--as-needed` then drops the shared library. Without an archive, or with
//! `IMULAB_HDF5_DYNAMIC` set, nothing changes: the shared library is linked as before.

use std::path::PathBuf;

fn main() {
    println!("cargo::rerun-if-env-changed=IMULAB_HDF5_DYNAMIC");
    println!("cargo::rerun-if-env-changed=DEP_HDF5_INCLUDE");
    if std::env::var_os("IMULAB_HDF5_DYNAMIC").is_some()
        || std::env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("linux")
    {
        return;
    }
    // The include directory hdf5-metno-sys found (…/include/hdf5/serial on Debian) tells
    // the flavour; its archive sits in the matching library directory.
    let include = std::env::var("DEP_HDF5_INCLUDE").unwrap_or_default();
    let multiarch = match std::env::var("CARGO_CFG_TARGET_ARCH").as_deref() {
        Ok("x86_64") => "x86_64-linux-gnu",
        Ok("aarch64") => "aarch64-linux-gnu",
        _ => return,
    };
    let flavour = if include.ends_with("/hdf5/serial") {
        "hdf5/serial"
    } else {
        ""
    };
    let candidates = [
        PathBuf::from(format!("/usr/lib/{multiarch}/{flavour}")),
        PathBuf::from(format!("/usr/lib/{multiarch}")),
    ];
    let Some(dir) = candidates.iter().find(|d| d.join("libhdf5.a").is_file()) else {
        return;
    };
    println!(
        "cargo::rerun-if-changed={}",
        dir.join("libhdf5.a").display()
    );
    println!("cargo::rustc-link-search=native={}", dir.display());
    println!("cargo::rustc-link-lib=static:+verbatim,-bundle=libhdf5.a");
    // What the archive itself needs (the shared library brought them along).
    for lib in ["sz", "z", "m", "dl"] {
        println!("cargo::rustc-link-lib=dylib={lib}");
    }
}
