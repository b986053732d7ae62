//! People bucketed by where they stand, so that each finds its nearest neighbours, and every
//! pair that could touch within a step, without measuring its distance to everyone: a search
//! goes out ring by ring of cells and stops at the ring beyond which nobody can be nearer
//! than the farthest neighbour kept, or within reach at all (as RVO2's k-d tree narrows its
//! range). What it finds is what measuring everyone would find: the grid only decides whom
//! to measure.

use crate::Point;

/// This few people or fewer go in one cell: measuring everyone costs less than bucketing.
const ONE_CELL_PEOPLE: usize = 16;
/// At most this many cells a side: people spread far apart get larger cells.
const MAX_CELLS_A_SIDE: f64 = 128.0;
/// A cell's side is stretched by this share, and a ring's distance shrunk by it, so that
/// rounding in where a person's cell is can never hide someone nearer than the bound.
const ROUNDING: f64 = 1e-9;

/// One person as the grid holds it.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Member {
    pub index: usize,
    pub position: Point,
    pub radius: f64,
    pub top_speed: f64,
}

/// People in square cells over the box they stand in, rebuilt every step.
#[derive(Debug, Clone, Default)]
pub(super) struct Grid {
    origin: Point,
    cell: f64,
    cols: usize,
    rows: usize,
    /// Each person's cell, column and row.
    at: Vec<(usize, usize)>,
    /// Where each cell's people begin in `members`; one entry more than cells.
    starts: Vec<usize>,
    /// The people, cell by cell, each cell's in ascending order of their indices, side by
    /// side in memory with what a search measures.
    members: Vec<Member>,
    /// Where the next person of each cell goes in `members`, while building.
    next: Vec<usize>,
    /// The largest radius and top speed among the people.
    max_radius: f64,
    max_speed: f64,
}

impl Grid {
    /// Buckets `people` (each one's position, radius and top speed) in cells no smaller than
    /// `min_cell`, nor so small that a cell holds under one person on average.
    pub(super) fn build(&mut self, people: impl Iterator<Item = (Point, f64, f64)> + Clone, min_cell: f64) {
        let (mut min, mut max) =
            (Point::new(f64::INFINITY, f64::INFINITY), Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY));
        let (mut n, mut max_radius, mut max_speed) = (0usize, 0.0f64, 0.0f64);
        for (p, radius, speed) in people.clone() {
            min = Point::new(min.re.min(p.re), min.im.min(p.im));
            max = Point::new(max.re.max(p.re), max.im.max(p.im));
            (n, max_radius, max_speed) = (n + 1, max_radius.max(radius), max_speed.max(speed));
        }
        let (width, height) = ((max.re - min.re).max(0.0), (max.im - min.im).max(0.0));
        let spread = (width * height / n.max(1) as f64).sqrt();
        let cell =
            (min_cell * (1.0 + ROUNDING)).max(spread).max(width / MAX_CELLS_A_SIDE).max(height / MAX_CELLS_A_SIDE);
        // Few people, or too far apart to bucket (a position beyond any floor): one cell,
        // everyone measured.
        let one_cell =
            n <= ONE_CELL_PEOPLE || !(cell.is_finite() && cell > 0.0 && min.re.is_finite() && min.im.is_finite());
        self.origin = if one_cell { Point::default() } else { min };
        self.cell = if one_cell { f64::INFINITY } else { cell };
        (self.cols, self.rows) =
            if one_cell { (1, 1) } else { ((width / cell) as usize + 1, (height / cell) as usize + 1) };
        (self.max_radius, self.max_speed) = (max_radius, max_speed);
        self.at.clear();
        self.starts.clear();
        self.starts.resize(self.cols * self.rows + 1, 0);
        for (p, _, _) in people.clone() {
            let at = self.cell_at(p);
            self.at.push(at);
            self.starts[at.0 + at.1 * self.cols + 1] += 1;
        }
        for c in 1..self.starts.len() {
            self.starts[c] += self.starts[c - 1];
        }
        // Filled in order, so each cell's people stay in ascending order.
        self.members.clear();
        self.members.resize(n, Member::default());
        self.next.clone_from(&self.starts);
        for (index, ((x, y), (position, radius, top_speed))) in self.at.iter().zip(people).enumerate() {
            let c = x + y * self.cols;
            self.members[self.next[c]] = Member { index, position, radius, top_speed };
            self.next[c] += 1;
        }
    }

    fn cell_at(&self, p: Point) -> (usize, usize) {
        if self.cell.is_infinite() {
            return (0, 0);
        }
        // Float to integer casts saturate (and take NaN to 0): always a cell of the grid.
        let x = (((p.re - self.origin.re) / self.cell).floor() as usize).min(self.cols - 1);
        let y = (((p.im - self.origin.im) / self.cell).floor() as usize).min(self.rows - 1);
        (x, y)
    }

    /// The largest radius and top speed among the people.
    pub(super) fn largest(&self) -> (f64, f64) {
        (self.max_radius, self.max_speed)
    }

    /// Calls `visit` with every person in the cells `k` cells from person `i`'s (the ring of
    /// cells at that Chebyshev distance; `k = 0`: its own), `i` among them.
    pub(super) fn ring(&self, i: usize, k: usize, mut visit: impl FnMut(&Member)) {
        let (cx, cy) = self.at[i];
        let (cx, cy, k) = (cx as isize, cy as isize, k as isize);
        for y in (cy - k).max(0)..=(cy + k).min(self.rows as isize - 1) {
            // The ring's top and bottom rows whole; between them, its two ends.
            let step = if (y - cy).abs() == k { 1 } else { 2 * k };
            let mut x = cx - k;
            while x <= cx + k {
                if (0..self.cols as isize).contains(&x) {
                    let c = x as usize + y as usize * self.cols;
                    self.members[self.starts[c]..self.starts[c + 1]].iter().for_each(&mut visit);
                }
                x += step.max(1);
            }
        }
    }

    /// Nobody beyond the ring `k` cells from person `i`'s is nearer to `i` than this; `None`
    /// when there is nobody beyond it (the rings so far cover the grid).
    pub(super) fn beyond(&self, i: usize, k: usize) -> Option<f64> {
        let (x, y) = self.at[i];
        let farthest = x.max(self.cols - 1 - x).max(y).max(self.rows - 1 - y);
        (k < farthest).then_some(k as f64 * self.cell * (1.0 - ROUNDING))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Every person's neighbours within `reach`, found ring by ring until the next ring is
    /// beyond reach, are those found by measuring everyone; and every pair nearer than a cell
    /// is in neighbouring cells.
    #[test]
    fn rings_find_whom_measuring_everyone_finds() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for (n, side, min_cell) in [(100, 7.0, 0.15), (40, 0.5, 0.15), (300, 30.0, 0.01), (1, 1.0, 0.1), (5, 0.0, 0.2)]
        {
            let people: Vec<Point> =
                (0..n).map(|_| Point::new(rng.random_range(0.0..=side), rng.random_range(0.0..=side) * 0.3)).collect();
            let mut grid = Grid::default();
            grid.build(people.iter().map(|&p| (p, 0.07, 0.1)), min_cell);
            for reach in [min_cell, 0.5, 2.0] {
                for i in 0..n {
                    let mut found = Vec::new();
                    for k in 0.. {
                        grid.ring(i, k, |m| {
                            assert_eq!(m.position, people[m.index]);
                            if (people[m.index] - people[i]).norm() < reach {
                                found.push(m.index);
                            }
                        });
                        if grid.beyond(i, k).is_none_or(|d| d >= reach) {
                            break;
                        }
                    }
                    found.sort_unstable();
                    let all: Vec<usize> = (0..n).filter(|&j| (people[j] - people[i]).norm() < reach).collect();
                    assert_eq!(found, all, "n {n}, reach {reach}, person {i}");
                }
            }
        }
    }

    /// A position beyond any floor puts everyone in one cell, measured alike.
    #[test]
    fn far_flung_people_share_one_cell() {
        let people = [Point::new(0.0, 0.0), Point::new(f64::INFINITY, 1.0), Point::new(f64::NAN, 0.0)];
        let mut grid = Grid::default();
        grid.build(people.iter().map(|&p| (p, 0.07, 0.1)), 0.1);
        let mut seen = Vec::new();
        grid.ring(0, 0, |m| seen.push(m.index));
        assert_eq!(seen, [0, 1, 2]);
        assert_eq!(grid.beyond(0, 0), None);
    }
}
