//! `easyhec-ur-worker`: the child process of the UR driver (`easyhec_drivers::ur::UrArm`).
//! It hosts Python and `ur_rtde` and answers one JSON line per request on stdin/stdout; it is
//! started by the driver, never by hand. Any argument is ignored.

fn main() -> std::process::ExitCode {
    easyhec_drivers::ur::serve_worker()
}
