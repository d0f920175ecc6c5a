//! Checks on what the daemon reads back from its data folder. Records, `active.json` and run
//! directories can be edited, restored from backups or damaged while the daemon is down, so
//! nothing read from disk is trusted: an id must be one the daemon could have made, a path
//! must stay inside the data folder, and a pose must be a rigid transform before anything
//! (a bump check, a robot controller reading `GET /api/v1/calibration`) relies on it.

use std::path::{Component, Path, PathBuf};

/// Largest calibration number: ids run `cal-0001` … `cal-999999999`. Keeping far below
/// `u64::MAX` means the next id can never wrap to `cal-0000`.
pub const MAX_ID: u64 = 999_999_999;

/// How far a rotation may be from orthonormal (largest entry of `RᵀR − I`), and its
/// determinant from +1, for a pose to count as rigid.
pub const RIGID_TOLERANCE: f64 = 1e-6;

/// The number of a well-formed id: `cal-` and the number written as the daemon writes it
/// (at least four digits, no other leading zeros), 1 to [`MAX_ID`].
pub fn id_number(id: &str) -> Option<u64> {
    let digits = id.strip_prefix("cal-")?;
    if digits.len() > 9 || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let n: u64 = digits.parse().ok()?;
    ((1..=MAX_ID).contains(&n) && id_for(n) == id).then_some(n)
}

/// The id of calibration number `n`.
pub fn id_for(n: u64) -> String {
    format!("cal-{n:04}")
}

/// Why an id is refused, for a one-line message.
pub fn id_problem(id: &str) -> String {
    format!("{id:?} is not an id this daemon makes (cal-0001 … cal-{MAX_ID})")
}

/// Checks that a row-major 4×4 is a rigid transform: finite, last row `0 0 0 1`, rotation
/// orthonormal and right-handed within [`RIGID_TOLERANCE`].
pub fn check_rigid(rows: &[[f64; 4]; 4]) -> Result<(), String> {
    for (r, row) in rows.iter().enumerate() {
        if let Some(c) = row.iter().position(|v| !v.is_finite()) {
            return Err(format!("entry [{r}][{c}] is {}, not finite", row[c]));
        }
    }
    let last = rows[3];
    let off = last[0].abs() + last[1].abs() + last[2].abs() + (last[3] - 1.0).abs();
    if off > RIGID_TOLERANCE {
        return Err(format!("last row is {last:?}, not [0, 0, 0, 1]"));
    }
    let r = nalgebra::Matrix3::from_fn(|i, j| rows[i][j]);
    let err = (r.transpose() * r - nalgebra::Matrix3::identity())
        .abs()
        .max();
    if err > RIGID_TOLERANCE {
        return Err(format!(
            "rotation is not orthonormal (largest entry of RᵀR − I is {err:.2e} > {RIGID_TOLERANCE:.0e})"
        ));
    }
    let det = r.determinant();
    if (det - 1.0).abs() > RIGID_TOLERANCE {
        return Err(format!("rotation has determinant {det:.6}, not +1"));
    }
    Ok(())
}

/// Checks that `b` is the inverse of `a` (both rigid), within [`RIGID_TOLERANCE`].
pub fn check_inverse(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> Result<(), String> {
    let m = |x: &[[f64; 4]; 4]| nalgebra::Matrix4::from_fn(|i, j| x[i][j]);
    let err = (m(a) * m(b) - nalgebra::Matrix4::identity()).abs().max();
    if err > RIGID_TOLERANCE {
        return Err(format!(
            "is not the inverse of camera_from_base (largest entry of the product minus I is {err:.2e})"
        ));
    }
    Ok(())
}

/// The data folder as the file system resolves it (symbolic links followed).
pub fn canonical_dir(dir: &Path) -> Result<PathBuf, String> {
    dir.canonicalize()
        .map_err(|e| format!("cannot resolve {}: {e}", dir.display()))
}

/// `rel` joined to the data folder, refused when it leaves it: an absolute path or a `..`
/// is refused as written, and an existing path is resolved (symbolic links followed) and
/// must still lie under `canonical`.
pub fn inside(dir: &Path, canonical: &Path, rel: &str) -> Result<PathBuf, String> {
    let lexical_ok = !rel.is_empty()
        && Path::new(rel)
            .components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    if !lexical_ok {
        return Err(format!("{rel:?} leaves the data folder"));
    }
    let path = dir.join(rel);
    resolved_inside(&path, canonical)?;
    Ok(path)
}

/// Resolves an existing `path` and checks that it lies under `canonical` (a missing path
/// passes: there is nothing it could point at).
pub fn resolved_inside(path: &Path, canonical: &Path) -> Result<(), String> {
    match path.canonicalize() {
        Ok(real) if real.starts_with(canonical) => Ok(()),
        Ok(real) => Err(format!(
            "{} resolves to {}, outside the data folder {}",
            path.display(),
            real.display(),
            canonical.display()
        )),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(format!("cannot resolve {}: {e}", path.display())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_canonical_and_bounded() {
        assert_eq!(id_number("cal-0001"), Some(1));
        assert_eq!(id_number("cal-12345"), Some(12345));
        assert_eq!(id_number("cal-999999999"), Some(MAX_ID));
        for bad in [
            "cal-0000",
            "cal-00001",
            "cal-1",
            "cal-18446744073709551615",
            "cal-1000000000",
            "cal-+001",
            "../cal-0001",
            "x-0001",
        ] {
            assert_eq!(id_number(bad), None, "{bad}");
        }
    }

    #[test]
    fn rigid_poses_pass_and_others_name_what_is_wrong() {
        let mut m = [
            [0.0, -1.0, 0.0, 0.1],
            [1.0, 0.0, 0.0, 0.2],
            [0.0, 0.0, 1.0, 0.3],
            [0.0, 0.0, 0.0, 1.0],
        ];
        assert_eq!(check_rigid(&m), Ok(()));
        let mut scaled = m;
        scaled[0][1] = -2.0;
        assert!(check_rigid(&scaled).unwrap_err().contains("orthonormal"));
        let mut mirrored = m;
        mirrored[2][2] = -1.0;
        assert!(check_rigid(&mirrored).unwrap_err().contains("determinant"));
        let mut bottom = m;
        bottom[3][0] = 0.5;
        assert!(check_rigid(&bottom).unwrap_err().contains("last row"));
        m[1][3] = f64::INFINITY;
        assert!(check_rigid(&m).unwrap_err().contains("[1][3]"));
    }

    #[test]
    fn paths_that_leave_the_data_folder_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let canonical = canonical_dir(dir.path()).unwrap();
        assert!(inside(dir.path(), &canonical, "runs/cal-0001").is_ok());
        for bad in ["../x", "/etc", "runs/../../x", ""] {
            assert!(inside(dir.path(), &canonical, bad).is_err(), "{bad}");
        }
        #[cfg(unix)]
        {
            let outside = tempfile::tempdir().unwrap();
            std::fs::create_dir(dir.path().join("runs")).unwrap();
            std::os::unix::fs::symlink(outside.path(), dir.path().join("runs/cal-0002")).unwrap();
            let e = inside(dir.path(), &canonical, "runs/cal-0002").unwrap_err();
            assert!(e.contains("outside the data folder"), "{e}");
        }
    }
}
