//! With the `ur` feature the UR driver's tests embed Python: point their rpath at the
//! libpython pyo3 linked, or the loader picks the system one, whose interpreter cannot see
//! the packages (`ur_rtde`) installed for the configured python3.

fn main() {
    #[cfg(feature = "ur")]
    pyo3_build_config::add_libpython_rpath_link_args();
}
