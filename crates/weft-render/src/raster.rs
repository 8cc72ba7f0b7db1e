//! The software rasterizer: z-buffered triangles with perspective-correct
//! smooth normals, two-sided Lambert shading under a key and a fill light,
//! supersampled and box-filtered down to the output size. A triangle thinner
//! than a pixel on screen (a ribbon seen edge-on) is drawn as its edges, one
//! pixel wide, so it shows as a line rather than vanishing between samples.
//!
//! Lights are fixed in view space (key from the upper left, fill from the
//! right), so every camera sees a lit front. Shading is done in sRGB values
//! directly: these are previews, and skipping the gamma round trip keeps a
//! frame to a few milliseconds.

use crate::camera::{Camera, Frame};
use crate::image::Image;
use glam::{DVec3, Vec3};

/// What a triangle is made of, which decides its colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Surface {
    /// Simulated cloth number `k` (counting cloth objects in input order):
    /// coloured [`CLOTH_COLORS`]`[k % len]`, front and back faces tinted
    /// differently, so that two cloths can be told apart.
    Cloth(usize),
    /// A kinematic obstacle: grey.
    Obstacle,
}

/// The two colours of one cloth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClothColor {
    /// Seen from the side its triangles' counter-clockwise normal points to.
    pub front: [u8; 3],
    /// Seen from the other side: a lighter tint of the same family.
    pub back: [u8; 3],
}

/// Background colour at the top of the image.
pub const BACKGROUND_TOP: [u8; 3] = [242, 245, 249];
/// Background colour at the bottom of the image.
pub const BACKGROUND_BOTTOM: [u8; 3] = [198, 207, 220];
/// Cloth colours in object order: hues far apart from each other, from the
/// grey obstacles and from the pale blue-grey background (the first cloth
/// keeps weft's terracotta and gold).
pub const CLOTH_COLORS: [ClothColor; 6] = [
    ClothColor {
        front: [222, 104, 60],
        back: [240, 184, 90],
    },
    ClothColor {
        front: [46, 110, 196],
        back: [124, 176, 232],
    },
    ClothColor {
        front: [56, 150, 78],
        back: [150, 206, 118],
    },
    ClothColor {
        front: [140, 80, 188],
        back: [198, 156, 228],
    },
    ClothColor {
        front: [24, 150, 158],
        back: [118, 212, 204],
    },
    ClothColor {
        front: [206, 66, 136],
        back: [238, 150, 192],
    },
];
/// Obstacles, either side.
pub const OBSTACLE: [u8; 3] = [158, 161, 168];

/// Corners whose smooth normal deviates from the face normal by more than
/// about 45° use the face normal: box edges and sharp folds stay crisp while
/// spheres and gentle cloth stay smooth.
const CREASE_COS: f32 = 0.7;
const AMBIENT: f32 = 0.30;
const KEY: f32 = 0.72;
const FILL: f32 = 0.28;

/// The (unnormalized) normal of the counter-clockwise triangle `a b c`, in
/// view space. View space (x right, y up, z forward) is a mirror image of
/// world space, so the cross product comes out reversed and is turned back.
fn normal(a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    (c - a).cross(b - a)
}

/// A reusable rasterizer for one output size; keeps its sample buffers between
/// frames.
#[derive(Clone, Debug)]
pub struct Rasterizer {
    width: u32,
    height: u32,
    ss: u32,
    depth: Vec<f32>,
    color: Vec<[u8; 3]>,
    /// Background colour per sample row.
    background: Vec<[u8; 3]>,
    view: Vec<Vec3>,
    normals: Vec<Vec3>,
    image: Image,
}

/// A clipped vertex: view-space position and (oriented) normal.
#[derive(Clone, Copy, Debug)]
struct Vert {
    p: Vec3,
    n: Vec3,
}

/// A vertex projected to sample space: position, `1 / z`, and the normal
/// times `1 / z` (both interpolate linearly on screen, which makes the
/// interpolation perspective-correct).
#[derive(Clone, Copy, Debug)]
struct Projected {
    x: f32,
    y: f32,
    iz: f32,
    nz: Vec3,
}

/// A triangle's base colour under the key and fill lights.
struct Shader {
    base: Vec3,
    key: Vec3,
    fill: Vec3,
}

impl Shader {
    fn new(color: [u8; 3]) -> Self {
        Self {
            base: Vec3::new(color[0] as f32, color[1] as f32, color[2] as f32),
            key: Vec3::new(-0.45, 0.65, -0.62).normalize(),
            fill: Vec3::new(0.75, 0.05, -0.55).normalize(),
        }
    }

    /// The colour of a sample with normal `n` (any length; zero gives the
    /// ambient term alone).
    fn shade(&self, n: Vec3) -> [u8; 3] {
        let n = n.normalize_or_zero();
        let light = AMBIENT + KEY * n.dot(self.key).max(0.0) + FILL * n.dot(self.fill).max(0.0);
        let c = (self.base * light).min(Vec3::splat(255.0));
        [c.x as u8, c.y as u8, c.z as u8]
    }
}

impl Rasterizer {
    /// A rasterizer for `width × height` images with `supersample ×
    /// supersample` samples per pixel.
    ///
    /// # Panics
    /// If a size or `supersample` is zero.
    pub fn new(width: u32, height: u32, supersample: u32) -> Self {
        assert!(width > 0 && height > 0 && supersample > 0, "empty image");
        let (sw, sh) = (width * supersample, height * supersample);
        let background = (0..sh)
            .map(|y| {
                let t = (y as f32 + 0.5) / sh as f32;
                std::array::from_fn(|c| {
                    let (a, b) = (BACKGROUND_TOP[c] as f32, BACKGROUND_BOTTOM[c] as f32);
                    (a + (b - a) * t + 0.5) as u8
                })
            })
            .collect();
        let n = sw as usize * sh as usize;
        Self {
            width,
            height,
            ss: supersample,
            depth: vec![f32::INFINITY; n],
            color: vec![[0; 3]; n],
            background,
            view: Vec::new(),
            normals: Vec::new(),
            image: Image::new(width, height, [0; 3]),
        }
    }

    /// Output width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Output height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Renders the triangles (`surfaces[f]` colours triangle `f`) seen by
    /// `camera` and returns the image.
    ///
    /// # Panics
    /// If the camera fails [`Camera::validate`], a triangle index is out of
    /// range, or `surfaces` and `triangles` differ in length.
    pub fn render(
        &mut self,
        positions: &[DVec3],
        triangles: &[[u32; 3]],
        surfaces: &[Surface],
        camera: &Camera,
    ) -> &Image {
        assert_eq!(surfaces.len(), triangles.len(), "one surface per triangle");
        let frame = camera.frame();
        // Clip a little in front of the eye; depth is linear view z in f32,
        // whose precision does not depend on this plane.
        let near = (1e-3 * (camera.target - camera.eye).length()) as f32;
        self.transform(positions, triangles, &frame);
        self.clear();
        for (t, &surface) in triangles.iter().zip(surfaces) {
            self.draw_triangle(t, surface, near, frame.focal as f32);
        }
        self.resolve();
        &self.image
    }

    /// View-space positions and area-weighted vertex normals.
    fn transform(&mut self, positions: &[DVec3], triangles: &[[u32; 3]], frame: &Frame) {
        self.view.clear();
        self.view
            .extend(positions.iter().map(|&p| frame.view_of(p).as_vec3()));
        self.normals.clear();
        self.normals.resize(positions.len(), Vec3::ZERO);
        for t in triangles {
            let [a, b, c] = t.map(|i| self.view[i as usize]);
            let n = normal(a, b, c);
            if n.is_finite() {
                for &i in t {
                    self.normals[i as usize] += n;
                }
            }
        }
        for n in &mut self.normals {
            *n = n.normalize_or_zero();
        }
    }

    fn clear(&mut self) {
        self.depth.fill(f32::INFINITY);
        let sw = (self.width * self.ss) as usize;
        for (row, &bg) in self.color.chunks_exact_mut(sw).zip(&self.background) {
            row.fill(bg);
        }
    }

    fn draw_triangle(&mut self, t: &[u32; 3], surface: Surface, near: f32, focal: f32) {
        let p = t.map(|i| self.view[i as usize]);
        let face = normal(p[0], p[1], p[2]);
        let len = face.length();
        if !(len > 0.0) || !len.is_finite() {
            return; // degenerate or non-finite: nothing to see
        }
        let face = face / len;
        // The eye is the view-space origin.
        let front = face.dot(-p[0]) > 0.0;
        let color = match (surface, front) {
            (Surface::Cloth(k), true) => CLOTH_COLORS[k % CLOTH_COLORS.len()].front,
            (Surface::Cloth(k), false) => CLOTH_COLORS[k % CLOTH_COLORS.len()].back,
            (Surface::Obstacle, _) => OBSTACLE,
        };
        let mut verts = [0, 1, 2].map(|k| {
            let n = self.normals[t[k] as usize];
            let n = if n.dot(face) >= CREASE_COS { n } else { face };
            Vert { p: p[k], n }
        });
        if !front {
            // Two-sided: shade the side the eye sees.
            for v in &mut verts {
                v.n = -v.n;
            }
        }
        if verts.iter().all(|v| v.p.z >= near) {
            self.fill(&verts, color, focal);
            return;
        }
        // Sutherland–Hodgman against the near plane: at most 4 vertices.
        let mut poly = [verts[0]; 4];
        let mut m = 0;
        for k in 0..3 {
            let (a, b) = (verts[k], verts[(k + 1) % 3]);
            let (ina, inb) = (a.p.z >= near, b.p.z >= near);
            if ina {
                poly[m] = a;
                m += 1;
            }
            if ina != inb {
                let s = (near - a.p.z) / (b.p.z - a.p.z);
                poly[m] = Vert {
                    p: a.p.lerp(b.p, s),
                    n: a.n.lerp(b.n, s),
                };
                m += 1;
            }
        }
        for k in 1..m.saturating_sub(1) {
            self.fill(&[poly[0], poly[k], poly[k + 1]], color, focal);
        }
    }

    /// Draws one triangle in front of the near plane: scan-converted, or as
    /// its three edges when it is thinner than a pixel on screen.
    fn fill(&mut self, v: &[Vert; 3], color: [u8; 3], focal: f32) {
        let sw = (self.width * self.ss) as f32;
        let sh = (self.height * self.ss) as f32;
        let scale = 0.5 * sh * focal;
        let s = v.map(|v| {
            let iz = 1.0 / v.p.z;
            Projected {
                x: 0.5 * sw + v.p.x * iz * scale,
                y: 0.5 * sh - v.p.y * iz * scale,
                iz,
                nz: v.n * iz,
            }
        });
        if !s.iter().all(|p| p.x.is_finite() && p.y.is_finite()) {
            return;
        }
        let area = (s[1].x - s[0].x) * (s[2].y - s[0].y) - (s[1].y - s[0].y) * (s[2].x - s[0].x);
        let longest = [(0, 1), (1, 2), (2, 0)]
            .map(|(a, b)| (s[b].x - s[a].x).hypot(s[b].y - s[a].y))
            .into_iter()
            .fold(0.0f32, f32::max);
        let shader = Shader::new(color);
        // A triangle thinner than a pixel (height = twice the area over the
        // longest side) can fall between the sample centres: a ribbon seen
        // edge-on would vanish or leave a trail of dots. Its edges, drawn one
        // pixel wide, make a continuous line and still cover the whole
        // triangle (every point of it is within half its height of an edge).
        if area.abs() <= self.ss as f32 * longest {
            for (a, b) in [(0, 1), (1, 2), (2, 0)] {
                self.line(&s[a], &s[b], &shader);
            }
        } else {
            self.scan(&s, area, &shader);
        }
    }

    /// Scan-converts a projected triangle of (twice the signed) `area` in
    /// samples, which is not zero.
    fn scan(&mut self, s: &[Projected; 3], area: f32, shader: &Shader) {
        let sw = (self.width * self.ss) as f32;
        let sh = (self.height * self.ss) as f32;
        let inv_area = 1.0 / area;
        let min_x = s[0].x.min(s[1].x).min(s[2].x);
        let max_x = s[0].x.max(s[1].x).max(s[2].x);
        let min_y = s[0].y.min(s[1].y).min(s[2].y);
        let max_y = s[0].y.max(s[1].y).max(s[2].y);
        // Sample centres are at integer + 0.5.
        let x0 = (min_x - 0.5).ceil().max(0.0) as usize;
        let x1 = ((max_x - 0.5).floor()).min(sw - 1.0);
        let y0 = (min_y - 0.5).ceil().max(0.0) as usize;
        let y1 = ((max_y - 0.5).floor()).min(sh - 1.0);
        if x1 < 0.0 || y1 < 0.0 {
            return;
        }
        let (x1, y1) = (x1 as usize, y1 as usize);
        if x0 > x1 || y0 > y1 {
            return;
        }
        // Edge k is opposite vertex k; e_k(p) / area is vertex k's barycentric.
        let edge = |a: usize, b: usize| {
            let (ax, ay) = (s[a].x, s[a].y);
            let (dx, dy) = (s[b].x - ax, s[b].y - ay);
            // e(p) = dx * (py - ay) - dy * (px - ax), scaled by 1 / area.
            (
                -dy * inv_area,
                dx * inv_area,
                (dy * ax - dx * ay) * inv_area,
            )
        };
        let e = [edge(1, 2), edge(2, 0), edge(0, 1)];
        let row_len = self.width as usize * self.ss as usize;
        for y in y0..=y1 {
            let py = y as f32 + 0.5;
            let row = y * row_len;
            for x in x0..=x1 {
                let px = x as f32 + 0.5;
                let b0 = e[0].0 * px + e[0].1 * py + e[0].2;
                let b1 = e[1].0 * px + e[1].1 * py + e[1].2;
                let b2 = e[2].0 * px + e[2].1 * py + e[2].2;
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                let iz = b0 * s[0].iz + b1 * s[1].iz + b2 * s[2].iz;
                let nz = s[0].nz * b0 + s[1].nz * b1 + s[2].nz * b2;
                self.plot(row + x, iz, nz, shader);
            }
        }
    }

    /// Draws the segment `a b` one pixel (`ss` samples) wide, with depth and
    /// normal interpolated along it. It steps one sample at a time along its
    /// longer axis, so the samples it covers are connected; a segment shorter
    /// than a sample covers the samples nearest its middle.
    fn line(&mut self, a: &Projected, b: &Projected, shader: &Shader) {
        let sw = (self.width * self.ss) as i64;
        let sh = (self.height * self.ss) as i64;
        let steep = (b.y - a.y).abs() > (b.x - a.x).abs();
        // (along, across) coordinates and the image's extent in each.
        let axes = |p: &Projected| if steep { (p.y, p.x) } else { (p.x, p.y) };
        let (len_along, len_across) = if steep { (sh, sw) } else { (sw, sh) };
        let ((a0, c0), (a1, c1)) = (axes(a), axes(b));
        let (lo, hi) = (a0.min(a1), a0.max(a1));
        // The samples whose centres (k + 0.5) lie between the ends.
        let (mut first, mut last) = ((lo - 0.5).ceil(), (hi - 0.5).floor());
        if first > last {
            first = (0.5 * (lo + hi) - 0.5).round();
            last = first;
        }
        let (first, last) = ((first as i64).max(0), (last as i64).min(len_along - 1));
        let half = 0.5 * self.ss as f32;
        let row_len = sw as usize;
        for k in first..=last {
            let t = if a1 != a0 {
                ((k as f32 + 0.5 - a0) / (a1 - a0)).clamp(0.0, 1.0)
            } else {
                0.5
            };
            let c = c0 + t * (c1 - c0);
            let iz = a.iz + t * (b.iz - a.iz);
            let nz = a.nz + t * (b.nz - a.nz);
            // The `ss` samples across whose centres lie within half a pixel.
            let m0 = ((c - half - 0.5).ceil() as i64).max(0);
            let m1 = ((c + half - 0.5).ceil() as i64 - 1).min(len_across - 1);
            for m in m0..=m1 {
                let (x, y) = if steep { (m, k) } else { (k, m) };
                self.plot(y as usize * row_len + x as usize, iz, nz, shader);
            }
        }
    }

    /// Depth-tests sample `i` at depth `1 / iz` and, when it is the nearest so
    /// far, shades it with the normal `nz` (any length).
    fn plot(&mut self, i: usize, iz: f32, nz: Vec3, shader: &Shader) {
        let z = 1.0 / iz;
        if z < self.depth[i] {
            self.depth[i] = z;
            self.color[i] = shader.shade(nz);
        }
    }

    /// Box-filters the samples into the output image.
    fn resolve(&mut self) {
        let ss = self.ss as usize;
        let (w, h) = (self.width as usize, self.height as usize);
        let row_len = w * ss;
        let norm = (ss * ss) as u32;
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0u32; 3];
                for sy in 0..ss {
                    let row = (y * ss + sy) * row_len + x * ss;
                    for c in &self.color[row..row + ss] {
                        acc[0] += c[0] as u32;
                        acc[1] += c[1] as u32;
                        acc[2] += c[2] as u32;
                    }
                }
                let o = 3 * (y * w + x);
                for k in 0..3 {
                    self.image.rgb[o + k] = ((acc[k] + norm / 2) / norm) as u8;
                }
            }
        }
    }
}
