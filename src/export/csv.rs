//! The seed table as CSV.

use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;

use super::Staged;
use crate::run::RunDir;
use crate::trace::{read_seeds, Stop};

/// The start of the header line of a seed table harmap wrote.
pub(super) const HEADER: &str = "x,y,z,theta,psi,phi,stop,stop_name,steps,length";

/// Write the seed table as CSV: x, y, z (world), theta, psi (radians; empty where the
/// seed did not reach the center), phi, stop code and name, steps, length, and for
/// surface seeds the vertex index.
pub fn seeds_csv(run: &RunDir, dest: &Path) -> Result<u64, crate::Error> {
    let t = read_seeds(run)?;
    let mut s = Staged::create(dest)?;
    let surface = !t.vertex.is_empty();
    let w = |s: &mut Staged, text: &str| s.out.write_all(text.as_bytes()).map_err(|e| s.io(e));
    let header = if surface {
        format!("{HEADER},vertex\n")
    } else {
        format!("{HEADER}\n")
    };
    w(&mut s, &header)?;
    let num = |v: f64| {
        if v.is_finite() {
            format!("{v}")
        } else {
            String::new()
        }
    };
    for i in 0..t.position.len() {
        let p = t.position[i];
        let name = Stop::ALL
            .iter()
            .find(|s| **s as u8 == t.stop[i])
            .map_or("unknown", |s| s.name());
        let mut line = format!(
            "{},{},{},{},{},{},{},{},{},{}",
            p.x,
            p.y,
            p.z,
            num(t.theta[i]),
            num(t.psi[i]),
            num(t.phi[i]),
            t.stop[i],
            name,
            t.steps[i],
            num(t.length[i])
        );
        if surface {
            let _ = write!(line, ",{}", t.vertex[i]);
        }
        line.push('\n');
        w(&mut s, &line)?;
    }
    s.commit()?;
    Ok(t.position.len() as u64)
}
