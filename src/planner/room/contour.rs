//! The free region's boundary traced as closed loops: marching squares on a grid of the
//! clearance, its zero crossings placed by linear interpolation, each loop walked with the
//! free region on its left, its sharp corners rounded and its points spaced evenly.

use crate::Point;

/// The zero set of `values` (on an `nx` by `ny` grid from `lo`, `cell` apart; positive is
/// free) as closed loops, the free region on the left of each.
pub fn loops(values: &[f64], nx: usize, ny: usize, lo: Point, cell: f64) -> Vec<Vec<Point>> {
    let at = |i: usize, j: usize| lo + Point::new(i as f64 * cell, j as f64 * cell);
    let v = |i: usize, j: usize| values[j * nx + i];
    // An edge's id: 2k for the one from node k rightwards, 2k + 1 for the one upwards.
    let crossing = |id: usize| {
        let k = id / 2;
        let (i, j) = (k % nx, k / nx);
        let (i2, j2) = if id.is_multiple_of(2) { (i + 1, j) } else { (i, j + 1) };
        let (a, b) = (v(i, j), v(i2, j2));
        let s = a / (a - b);
        at(i, j) + (at(i2, j2) - at(i, j)) * s
    };
    let mut links: std::collections::HashMap<usize, Vec<usize>> = std::collections::HashMap::new();
    let mut link = |a: usize, b: usize| {
        links.entry(a).or_default().push(b);
        links.entry(b).or_default().push(a);
    };
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            let k = j * nx + i;
            let (bottom, right, top, left) = (2 * k, 2 * (k + 1) + 1, 2 * (k + nx), 2 * k + 1);
            let free = [v(i, j) > 0.0, v(i + 1, j) > 0.0, v(i + 1, j + 1) > 0.0, v(i, j + 1) > 0.0];
            let cuts: Vec<usize> = [(bottom, 0, 1), (right, 1, 2), (top, 3, 2), (left, 0, 3)]
                .iter()
                .filter(|&&(_, a, b)| free[a] != free[b])
                .map(|&(e, _, _)| e)
                .collect();
            match cuts.len() {
                2 => link(cuts[0], cuts[1]),
                4 => {
                    // A saddle: the centre's sign says which corners the loops cut off.
                    let centre_free = (v(i, j) + v(i + 1, j) + v(i + 1, j + 1) + v(i, j + 1)) > 0.0;
                    if centre_free == free[0] {
                        link(bottom, right);
                        link(top, left);
                    } else {
                        link(bottom, left);
                        link(right, top);
                    }
                }
                _ => {}
            }
        }
    }
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    let mut starts: Vec<usize> = links.keys().copied().collect();
    starts.sort_unstable();
    for start in starts {
        if seen.contains(&start) {
            continue;
        }
        let mut ids = vec![start];
        seen.insert(start);
        let mut current = start;
        loop {
            let next = links[&current].iter().copied().find(|n| !seen.contains(n));
            match next {
                Some(n) => {
                    seen.insert(n);
                    ids.push(n);
                    current = n;
                }
                None => break,
            }
        }
        if ids.len() >= 3 {
            out.push(ids.into_iter().map(crossing).collect());
        }
    }
    out
}

/// Orient `points` (a closed loop) so that `free` is larger on its left.
pub fn orient(points: &mut [Point], free: impl Fn(Point) -> f64) {
    let n = points.len();
    let (mut left, mut right) = (0.0, 0.0);
    for k in (0..n).step_by((n / 16).max(1)) {
        let (a, b) = (points[k], points[(k + 1) % n]);
        let d = b - a;
        if d.norm() == 0.0 {
            continue;
        }
        let side = d / d.norm() * Point::new(0.0, 0.01);
        let mid = (a + b) * 0.5;
        left += free(mid + side);
        right += free(mid - side);
    }
    if right > left {
        points.reverse();
    }
}

/// Round a closed loop's corners (a moving average over `window` metres of its arc length,
/// twice) and space its points about `spacing` apart; with `corner_turn`, closer where the
/// loop turns left ([`grade`]).
pub fn smooth_and_space(points: &[Point], window: f64, spacing: f64, corner_turn: Option<f64>) -> Vec<Point> {
    // Graded panels need a finer curve to cut (the same window's average, in more points).
    let half = if corner_turn.is_some() { 16 } else { 4 };
    let fine = resample(points, window / (2 * half) as f64);
    let n = fine.len();
    if n < 2 * half + 1 {
        return resample(points, spacing);
    }
    let mut smooth = fine.clone();
    for _ in 0..2 {
        let prev = smooth.clone();
        for (k, s) in smooth.iter_mut().enumerate() {
            let sum: Point = (0..=2 * half).map(|d| prev[(k + n + d - half) % n]).sum::<Point>();
            *s = sum / (2 * half + 1) as f64;
        }
    }
    match corner_turn {
        Some(turn) => grade(&smooth, spacing, turn),
        None => resample(&smooth, spacing),
    }
}

/// The closest the points come in a corner, as a fraction of the spacing.
const MIN_SPACING: f64 = 0.05;

/// A finely sampled smooth loop's points `spacing` apart, and closer where it turns left
/// (a corner of the free region, which the loop keeps on its left): there no panel turns
/// more than `max_turn` (rad) from the next. The exact flow is slow in such a corner, and a
/// constant density's error, which grows with the panel's length and the turn between
/// panels, would not be. The points fall where the count `∫ ds / h(s)` crosses a whole
/// number, `h` the wanted spacing, so they grade smoothly.
fn grade(fine: &[Point], spacing: f64, max_turn: f64) -> Vec<Point> {
    let n = fine.len();
    let length = |k: usize| (fine[(k + 1) % n] - fine[k]).norm();
    // The wanted spacing on each fine segment, from the turn at its two ends.
    let wanted: Vec<f64> = (0..n)
        .map(|k| {
            let (a, b) = (fine[k], fine[(k + 1) % n]);
            let turn = |u: Point, v: Point| if u.norm() > 0.0 && v.norm() > 0.0 { (v / u).arg() } else { 0.0 };
            let here = turn(a - fine[(k + n - 1) % n], b - a).max(0.0) + turn(b - a, fine[(k + 2) % n] - b).max(0.0);
            let curvature = here / (2.0 * length(k).max(1e-12));
            if curvature > 0.0 {
                (max_turn / curvature).clamp(spacing * MIN_SPACING, spacing)
            } else {
                spacing
            }
        })
        .collect();
    let count: f64 = (0..n).map(|k| length(k) / wanted[k]).sum();
    let panels = (count.round() as usize).max(3);
    let scale = count / panels as f64;
    let mut out = Vec::with_capacity(panels);
    let mut walked = 0.0;
    for k in 0..n {
        let step = length(k) / wanted[k] / scale;
        let mut next = out.len() as f64;
        while next < walked + step && out.len() < panels {
            out.push(fine[k] + (fine[(k + 1) % n] - fine[k]) * ((next - walked) / step));
            next += 1.0;
        }
        walked += step;
    }
    out
}

/// A closed loop's points respaced evenly, about `spacing` apart along its length.
fn resample(points: &[Point], spacing: f64) -> Vec<Point> {
    let n = points.len();
    let lengths: Vec<f64> = (0..n).map(|k| (points[(k + 1) % n] - points[k]).norm()).collect();
    let total: f64 = lengths.iter().sum();
    let count = ((total / spacing).round() as usize).max(3);
    let step = total / count as f64;
    let mut out = Vec::with_capacity(count);
    let (mut k, mut walked) = (0usize, 0.0);
    for m in 0..count {
        let target = m as f64 * step;
        while walked + lengths[k] < target && k + 1 < n {
            walked += lengths[k];
            k += 1;
        }
        let s = if lengths[k] > 0.0 { (target - walked) / lengths[k] } else { 0.0 };
        out.push(points[k] + (points[(k + 1) % n] - points[k]) * s);
    }
    out
}
