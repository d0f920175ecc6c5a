//! Procedural textures of the simulated cell: value noise, and the clutter of the hard preset
//! (posters, shelves of books and boxes, picture frames, clocks and cables on the wall; paper,
//! books, cutting mats, keyboards, tape rolls and cables on the table).
//!
//! Clutter needs no list of objects: each wall or table surface is cut into cells, and a hash of
//! a cell's index and the seed decides what the cell holds and where. A pixel looks up only its
//! own cell, so clutter costs the same per pixel however much wall the camera sees, and the same
//! seed always gives the same room.

/// Smooth value noise in [0, 1] (hash lattice, bilinear), for textures.
pub(crate) fn value_noise(x: f64, y: f64, seed: u32) -> f64 {
    fn hash(ix: i64, iy: i64, seed: u32) -> f64 {
        let mut h = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ u64::from(seed).wrapping_mul(0x1656_67B1_9E37_79F9);
        h ^= h >> 29;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 32;
        (h & 0xFFFF) as f64 / 65535.0
    }
    let (fx, fy) = (x.floor(), y.floor());
    let (tx, ty) = (x - fx, y - fy);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let (ix, iy) = (fx as i64, fy as i64);
    let a = hash(ix, iy, seed) * (1.0 - sx) + hash(ix + 1, iy, seed) * sx;
    let b = hash(ix, iy + 1, seed) * (1.0 - sx) + hash(ix + 1, iy + 1, seed) * sx;
    a * (1.0 - sy) + b * sy
}

/// Three octaves of [`value_noise`], in [0, 1].
pub(crate) fn fractal(x: f64, y: f64, seed: u32) -> f64 {
    (value_noise(x, y, seed) * 0.5
        + value_noise(x * 2.1, y * 2.1, seed + 1) * 0.3
        + value_noise(x * 4.3, y * 4.3, seed + 2) * 0.2)
        .clamp(0.0, 1.0)
}

/// A well-mixed 64-bit hash of three integers (splitmix64 finaliser over their combination).
pub(crate) fn mix(a: u64, b: u64, c: u64) -> u64 {
    let mut h = a.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ b.rotate_left(21).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ c.rotate_left(42).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 30;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 27;
    h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^ (h >> 31)
}

/// A tiny deterministic stream of uniform numbers (splitmix64), for per-cell item parameters:
/// far cheaper to start than a ChaCha generator, which matters once per pixel.
struct Draws(u64);

impl Draws {
    fn new(a: u64, b: u64, c: u64) -> Draws {
        Draws(mix(a, b, c))
    }

    /// Uniform in [0, 1).
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }

    /// One of `items`, uniformly.
    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[((self.next() * items.len() as f64) as usize).min(items.len() - 1)]
    }
}

/// Linear-RGB albedos of everyday things; white and light grey come twice, because a white
/// sheet of paper beside a white robot is what makes segmentation hard.
const ITEM_COLOURS: [[f64; 3]; 16] = [
    [0.88, 0.87, 0.84],
    [0.86, 0.86, 0.86],
    [0.82, 0.76, 0.6],
    [0.7, 0.71, 0.72],
    [0.62, 0.63, 0.65],
    [0.05, 0.05, 0.06],
    [0.6, 0.08, 0.07],
    [0.08, 0.2, 0.55],
    [0.1, 0.4, 0.15],
    [0.85, 0.7, 0.1],
    [0.8, 0.35, 0.05],
    [0.05, 0.45, 0.45],
    [0.55, 0.4, 0.25],
    [0.35, 0.15, 0.45],
    [0.9, 0.9, 0.88],
    [0.25, 0.25, 0.27],
];

/// Cable colours: black, white, grey, orange, blue.
const CABLE_COLOURS: [[f64; 3]; 5] = [
    [0.03, 0.03, 0.03],
    [0.85, 0.85, 0.83],
    [0.35, 0.35, 0.36],
    [0.8, 0.3, 0.03],
    [0.05, 0.15, 0.6],
];

const WALL_STREAM: u64 = 0x5741_4C4C;
const WALL_CABLE_STREAM: u64 = 0x5743_4142;
const TABLE_STREAM: u64 = 0x5441_424C;
const TABLE_CABLE_STREAM: u64 = 0x5443_4142;

fn scale(c: [f64; 3], k: f64) -> [f64; 3] {
    c.map(|v| v * k)
}

/// Lines of "text": dark glyphs (3x3 random sub-blocks) on `paper`, in `rows` lines across
/// normalised coordinates `(u, v)` (`v` runs down the page). High-frequency edges everywhere.
fn text_page(u: f64, v: f64, rows: f64, seed: u64, paper: [f64; 3], ink: [f64; 3]) -> [f64; 3] {
    let row_f = v * rows;
    let row = row_f.floor();
    let in_row = row_f - row;
    if !(0.25..0.8).contains(&in_row) {
        return paper;
    }
    let mut line = Draws::new(seed, row as u64, 1);
    let line_end = line.range(0.45, 1.0);
    if u > line_end || line.next() < 0.12 {
        return paper;
    }
    let chars_per_row = (rows * 2.2).max(12.0);
    let char_f = u * chars_per_row;
    let char_index = char_f.floor();
    if Draws::new(seed, row as u64, 1000 + char_index as u64).next() < 0.18 {
        return paper; // a space between words
    }
    let sub_x = ((char_f - char_index) * 3.0).floor() as u64;
    let sub_y = (((in_row - 0.25) / 0.55) * 3.0).floor() as u64;
    let glyph = Draws::new(mix(seed, row as u64, char_index as u64), sub_x, sub_y).next();
    if glyph < 0.55 {
        ink
    } else {
        paper
    }
}

/// A poster, print or chart, in normalised item coordinates (`v` runs down).
fn poster(u: f64, v: f64, d: &mut Draws, seed: u64) -> [f64; 3] {
    let frame = d.pick(&ITEM_COLOURS);
    if !(0.04..0.96).contains(&u) || !(0.04..0.96).contains(&v) {
        return frame;
    }
    let a = d.pick(&ITEM_COLOURS);
    let b = d.pick(&ITEM_COLOURS);
    let content = d.next();
    if content < 0.3 {
        // A printed page: title bar, then text.
        let paper = if d.next() < 0.7 {
            [0.88, 0.87, 0.84]
        } else {
            a
        };
        if v < 0.18 {
            return if (0.1..0.9).contains(&u) && v > 0.06 {
                b
            } else {
                paper
            };
        }
        text_page(
            u,
            (v - 0.18) / 0.82,
            d.range(8.0, 22.0),
            seed,
            paper,
            [0.04; 3],
        )
    } else if content < 0.5 {
        // Stripes at an angle.
        let angle = d.range(0.0, std::f64::consts::PI);
        let period = d.range(0.03, 0.15);
        let s = (u * angle.cos() + v * angle.sin()) / period;
        if s.rem_euclid(1.0) < 0.5 {
            a
        } else {
            b
        }
    } else if content < 0.65 {
        // A checkerboard.
        let n = d.range(4.0, 14.0);
        if ((u * n).floor() as i64 + (v * n).floor() as i64).rem_euclid(2) == 0 {
            a
        } else {
            b
        }
    } else if content < 0.85 {
        // A chart of coloured blocks.
        let (nx, ny) = (d.range(2.0, 5.0).floor(), d.range(2.0, 6.0).floor());
        let (cx, cy) = ((u * nx).floor(), (v * ny).floor());
        let edge = (u * nx).fract() < 0.06 || (v * ny).fract() < 0.06;
        if edge {
            [0.9; 3]
        } else {
            Draws::new(seed, cx as u64, 77 + cy as u64).pick(&ITEM_COLOURS)
        }
    } else {
        // A photograph: two colours blended by noise.
        let t = fractal(u * 6.0, v * 6.0, seed as u32);
        [0, 1, 2].map(|c| a[c] * t + b[c] * (1.0 - t))
    }
}

/// A shelf plank with books and boxes standing on it (`v` runs up from the plank).
fn shelf(u: f64, v: f64, seed: u64) -> Option<[f64; 3]> {
    if v < 0.08 {
        let grain = 0.85 + 0.15 * value_noise(u * 60.0, v * 4.0, seed as u32);
        return Some(scale([0.32, 0.2, 0.1], grain));
    }
    let slots = 11.0;
    let slot_f = u * slots;
    let slot = slot_f.floor();
    let mut d = Draws::new(seed, slot as u64, 5);
    if d.next() < 0.2 {
        return None;
    }
    let height = d.range(0.35, 0.95);
    let top = 0.08 + 0.92 * height;
    if v > top || slot_f - slot < 0.05 {
        return None;
    }
    let colour = d.pick(&ITEM_COLOURS);
    // A label band on the spine.
    let band = (v - 0.08) / (top - 0.08);
    if (0.62..0.7).contains(&band) || (0.15..0.18).contains(&band) {
        Some(scale(colour, if colour[0] > 0.5 { 0.55 } else { 2.2 }).map(|c| c.min(0.95)))
    } else {
        Some(colour)
    }
}

/// What the wall shows at direction `(az_rad, el_rad)` from the robot, when clutter covers it
/// (`None`: bare wall). `density` is the fraction of wall cells holding something.
pub(crate) fn wall_clutter(
    az_rad: f64,
    el_rad: f64,
    seed: u64,
    density: f64,
    cables: u32,
) -> Option<[f64; 3]> {
    if let Some(c) = cable(az_rad, el_rad, seed ^ WALL_CABLE_STREAM, cables, 0.5, 0.005) {
        return Some(c);
    }
    const CELL_AZ: f64 = 0.3;
    const CELL_EL: f64 = 0.22;
    let row = (el_rad / CELL_EL).floor();
    if !(-2.0..=3.0).contains(&row) {
        return None;
    }
    let shift = if (row as i64).rem_euclid(2) == 1 {
        0.5
    } else {
        0.0
    };
    let col = (az_rad / CELL_AZ + shift).floor();
    let lx = az_rad / CELL_AZ + shift - col;
    let ly = el_rad / CELL_EL - row;
    let cell_seed = mix(col as i64 as u64, row as i64 as u64, seed ^ WALL_STREAM);
    let mut d = Draws(cell_seed);
    if d.next() >= density {
        return None;
    }
    let kind = d.next();
    let (w, h) = if kind < 0.3 {
        // Shelves are wide and low.
        (d.range(0.75, 0.95), d.range(0.45, 0.7))
    } else if kind > 0.9 {
        // Small things: a clock, a switch.
        (d.range(0.12, 0.25), d.range(0.15, 0.3))
    } else {
        (d.range(0.35, 0.85), d.range(0.4, 0.9))
    };
    let x0 = d.range(0.02, 0.98 - w);
    let y0 = d.range(0.03, 0.97 - h);
    if lx < x0 || lx > x0 + w || ly < y0 || ly > y0 + h {
        return None;
    }
    let (u, v_up) = ((lx - x0) / w, (ly - y0) / h);
    if kind < 0.3 {
        shelf(u, v_up, cell_seed)
    } else if kind <= 0.9 {
        Some(poster(u, 1.0 - v_up, &mut d, cell_seed))
    } else if d.next() < 0.5 {
        // A wall clock: dark rim, white face, two hands.
        let (du, dv) = (u - 0.5, v_up - 0.5);
        let r = (du * du + dv * dv).sqrt();
        if r > 0.5 {
            None
        } else if r > 0.43 {
            Some([0.04; 3])
        } else {
            let angle = dv.atan2(du);
            let hand = |a: f64, len: f64| (angle - a).sin().abs() * r < 0.025 && r < len;
            if hand(1.2, 0.3) || hand(-0.4, 0.4) {
                Some([0.03; 3])
            } else {
                Some([0.9, 0.9, 0.88])
            }
        }
    } else {
        // A light switch: a white plate with a darker rocker.
        if (0.35..0.65).contains(&u) && (0.3..0.7).contains(&v_up) {
            Some([0.7, 0.7, 0.68])
        } else {
            Some([0.9, 0.9, 0.88])
        }
    }
}

/// A cable of `count` seeded sagging curves across the first coordinate: `(x, y)` in units
/// where curves sit in y ∈ [-`y_range`, `y_range`], `thickness` the half width.
fn cable(x: f64, y: f64, seed: u64, count: u32, y_range: f64, thickness: f64) -> Option<[f64; 3]> {
    for k in 0..count {
        let mut d = Draws::new(seed, u64::from(k), 9);
        let base = d.range(-y_range, y_range);
        let amp = d.range(0.2, 1.0) * y_range * 0.25;
        let freq = d.range(2.0, 9.0) / y_range.max(1e-9) * 0.3;
        let phase = d.range(0.0, std::f64::consts::TAU);
        let half = thickness * d.range(0.7, 1.4);
        let colour = d.pick(&CABLE_COLOURS);
        let arg = freq * x + phase;
        let centre = base + amp * arg.sin();
        let slope = amp * freq * arg.cos();
        let dist = (y - centre).abs() / (1.0 + slope * slope).sqrt();
        if dist < half {
            // Round cross-section: brighter along the middle.
            let t = dist / half;
            return Some(scale(colour, 0.55 + 0.6 * (1.0 - t * t).sqrt()).map(|c| c.min(1.0)));
        }
    }
    None
}

/// What lies on the table at base-frame `(x_m, y_m)`, when clutter covers it (`None`: wood).
pub(crate) fn table_clutter(
    x_m: f64,
    y_m: f64,
    seed: u64,
    density: f64,
    cables: u32,
) -> Option<[f64; 3]> {
    if let Some(c) = cable(x_m, y_m, seed ^ TABLE_CABLE_STREAM, cables, 0.7, 0.004) {
        return Some(c);
    }
    const CELL_M: f64 = 0.32;
    let (col, row) = ((x_m / CELL_M).floor(), (y_m / CELL_M).floor());
    let cell_seed = mix(col as i64 as u64, row as i64 as u64, seed ^ TABLE_STREAM);
    let mut d = Draws(cell_seed);
    if d.next() >= density {
        return None;
    }
    let kind = d.next();
    let centre = [
        (col + d.range(0.4, 0.6)) * CELL_M,
        (row + d.range(0.4, 0.6)) * CELL_M,
    ];
    let yaw = d.range(0.0, std::f64::consts::PI);
    let half_len = d.range(0.06, 0.14);
    let half_wid = d.range(0.04, half_len);
    let (dx, dy) = (x_m - centre[0], y_m - centre[1]);
    if kind > 0.88 {
        // A tape roll or a mug seen from above: a ring.
        let r = (dx * dx + dy * dy).sqrt();
        let outer = half_wid.min(0.06);
        return if r < outer && r > outer * 0.55 {
            Some(d.pick(&ITEM_COLOURS))
        } else {
            None
        };
    }
    let (s, c) = yaw.sin_cos();
    let lu = c * dx + s * dy;
    let lv = -s * dx + c * dy;
    if lu.abs() > half_len || lv.abs() > half_wid {
        return None;
    }
    let (u, v) = ((lu / half_len + 1.0) / 2.0, (lv / half_wid + 1.0) / 2.0);
    Some(if kind < 0.3 {
        // A printed sheet.
        text_page(u, v, 24.0, cell_seed, [0.88, 0.87, 0.84], [0.03; 3])
    } else if kind < 0.5 {
        // A book: cover colour, a lighter title block, a spine.
        let cover = d.pick(&ITEM_COLOURS);
        if u < 0.06 {
            scale(cover, 0.6)
        } else if (0.25..0.85).contains(&u) && (0.55..0.75).contains(&v) {
            [0.85, 0.84, 0.8]
        } else {
            cover
        }
    } else if kind < 0.65 {
        // A cutting mat: a 1 cm grid, heavier every 5 cm.
        let (gx, gy) = (lu * 100.0, lv * 100.0);
        let heavy = (gx / 5.0).rem_euclid(1.0) < 0.04 || (gy / 5.0).rem_euclid(1.0) < 0.04;
        let light = gx.rem_euclid(1.0) < 0.1 || gy.rem_euclid(1.0) < 0.1;
        if heavy || light {
            [0.7, 0.75, 0.65]
        } else {
            [0.05, 0.25, 0.12]
        }
    } else if kind < 0.8 {
        // A keyboard: a grid of keys with light gaps.
        let (kx, ky) = (lu / 0.019, lv / 0.019);
        if kx.rem_euclid(1.0) < 0.15 || ky.rem_euclid(1.0) < 0.15 {
            [0.55, 0.55, 0.56]
        } else {
            [0.08, 0.08, 0.09]
        }
    } else {
        // A tray with a lighter rim.
        if !(0.06..=0.94).contains(&u) || !(0.08..=0.92).contains(&v) {
            [0.45, 0.45, 0.47]
        } else {
            scale(d.pick(&ITEM_COLOURS), 0.8)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clutter_is_a_function_of_the_seed() {
        let sample = |seed: u64| -> Vec<Option<[f64; 3]>> {
            (0..400)
                .map(|i| {
                    let (x, y) = (f64::from(i % 20) * 0.05, f64::from(i / 20) * 0.05);
                    table_clutter(x, y, seed, 0.8, 3)
                })
                .collect()
        };
        assert_eq!(sample(4), sample(4));
        assert_ne!(sample(4), sample(5));
        let covered = sample(4).iter().filter(|c| c.is_some()).count();
        assert!(covered > 40 && covered < 360, "{covered} of 400 covered");
    }
}
