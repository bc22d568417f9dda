//! Compiles the OpenMesh shim (`openmesh/shim.cpp`) when the `openmesh`
//! feature is on; nothing otherwise.

fn main() {
    println!("cargo:rerun-if-changed=openmesh/shim.cpp");
    if std::env::var_os("CARGO_FEATURE_OPENMESH").is_none() {
        return;
    }
    cc::Build::new()
        .cpp(true)
        .file("openmesh/shim.cpp")
        .flag_if_supported("-std=c++17")
        .opt_level(2)
        .define("NDEBUG", None)
        // OpenMesh's headers warn about their own code.
        .warnings(false)
        .compile("raymesh_openmesh_shim");
    println!("cargo:rustc-link-lib=OpenMeshTools");
    println!("cargo:rustc-link-lib=OpenMeshCore");
}
