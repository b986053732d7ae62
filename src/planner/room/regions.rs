//! The room's free floor cut into connected regions, and the clearance of a point from the
//! room's boundary.

use super::{segment_distance, RoomShape};
use crate::Point;
use flowgate_protocol::plane::{inside_polygon, polygon_edges};

/// The free region's connected parts, on a grid over the room's extent (its points and a
/// margin), made once with the room: which part a point lies in, and each part's area,
/// centroid and whether it is closed (never reaching the extent's border).
#[derive(Debug, Clone)]
pub(super) struct Regions {
    pub(super) lo: Point,
    pub(super) cell: f64,
    pub(super) nx: usize,
    pub(super) ny: usize,
    /// Per grid node: the clearance there, and 0 where the robot's centre may not be, else
    /// its part's number + 1.
    pub(super) clearance: Vec<f64>,
    label: Vec<u16>,
    pub(super) parts: Vec<Part>,
}

#[derive(Debug, Clone)]
pub(super) struct Part {
    pub(super) area: f64,
    pub(super) centroid: Point,
    pub(super) closed: bool,
    /// A closed part's closure: the sources' strengths that make its radial flow tangent at
    /// the boundary, per unit source density.
    pub(super) closure: Option<Vec<f64>>,
}

/// Cells across the room's larger extent.
pub(super) const GRID_CELLS: f64 = 400.0;

impl Regions {
    pub(super) fn new(shape: &RoomShape, grow: f64) -> Self {
        let all: Vec<Point> =
            shape.walls.iter().chain(&shape.obstacles).chain(shape.view.iter()).flatten().copied().collect();
        let start = (Point::new(f64::MAX, f64::MAX), Point::new(f64::MIN, f64::MIN));
        let (lo, hi) = all.iter().fold(start, |(lo, hi), p| {
            (Point::new(lo.re.min(p.re), lo.im.min(p.im)), Point::new(hi.re.max(p.re), hi.im.max(p.im)))
        });
        let margin = 2.0 * grow + 0.05;
        let (lo, hi) = (lo - Point::new(margin, margin), hi + Point::new(margin, margin));
        let cell = (hi.re - lo.re).max(hi.im - lo.im) / GRID_CELLS;
        let nx = ((hi.re - lo.re) / cell).ceil() as usize + 1;
        let ny = ((hi.im - lo.im) / cell).ceil() as usize + 1;
        let mut regions = Self { lo, cell, nx, ny, clearance: Vec::new(), label: vec![0; nx * ny], parts: Vec::new() };
        regions.clearance = (0..nx * ny).map(|k| clearance(shape, grow, regions.centre(k))).collect();
        let free: Vec<bool> = regions.clearance.iter().map(|&c| c > 0.0).collect();
        for seed in 0..nx * ny {
            if free[seed] && regions.label[seed] == 0 && regions.parts.len() < usize::from(u16::MAX - 1) {
                let part = regions.flood(seed, &free);
                regions.parts.push(part);
            }
        }
        regions
    }

    fn centre(&self, k: usize) -> Point {
        self.lo + Point::new((k % self.nx) as f64 * self.cell, (k / self.nx) as f64 * self.cell)
    }

    fn flood(&mut self, seed: usize, free: &[bool]) -> Part {
        let id = self.parts.len() as u16 + 1;
        let (nx, ny) = (self.nx, self.ny);
        let mut stack = vec![seed];
        self.label[seed] = id;
        let (mut count, mut sum, mut open) = (0usize, Point::default(), false);
        while let Some(k) = stack.pop() {
            let (i, j) = (k % nx, k / nx);
            count += 1;
            sum += self.centre(k);
            open |= i == 0 || j == 0 || i == nx - 1 || j == ny - 1;
            for (a, b) in [(i.wrapping_sub(1), j), (i + 1, j), (i, j.wrapping_sub(1)), (i, j + 1)] {
                if a < nx && b < ny && free[b * nx + a] && self.label[b * nx + a] == 0 {
                    self.label[b * nx + a] = id;
                    stack.push(b * nx + a);
                }
            }
        }
        Part { area: count as f64 * self.cell * self.cell, centroid: sum / count as f64, closed: !open, closure: None }
    }

    /// The part `p` lies in, if any (the nearest cell's). Beyond the grid's extent lies the
    /// open plane round the room, which the extent's free margin joins into one open part.
    pub(super) fn part_of(&self, p: Point) -> Option<usize> {
        let i = ((p.re - self.lo.re) / self.cell).round();
        let j = ((p.im - self.lo.im) / self.cell).round();
        if !(i >= 0.0 && j >= 0.0 && (i as usize) < self.nx && (j as usize) < self.ny) {
            return self.parts.iter().position(|part| !part.closed);
        }
        let label = self.label[j as usize * self.nx + i as usize];
        (label > 0).then(|| usize::from(label) - 1)
    }
}

/// The clearance of a robot centre at `p`: its distance to the nearest grown wall or
/// obstacle, or to the view's edge (negative where it may not be).
pub fn clearance(shape: &RoomShape, grow: f64, p: Point) -> f64 {
    let mut d = f64::INFINITY;
    for wall in &shape.walls {
        for s in wall.windows(2) {
            d = d.min(segment_distance(p, s[0], s[1]));
        }
    }
    for polygon in &shape.obstacles {
        let edge = polygon_edges(polygon).map(|(a, b)| segment_distance(p, a, b)).fold(f64::INFINITY, f64::min);
        d = d.min(if inside_polygon(p, polygon) { -edge } else { edge });
    }
    let d = d - grow;
    match &shape.view {
        Some(view) => {
            let edge = polygon_edges(view).map(|(a, b)| segment_distance(p, a, b)).fold(f64::INFINITY, f64::min);
            d.min(if inside_polygon(p, view) { edge } else { -edge })
        }
        None => d,
    }
}
