//! Scene primitives (boxes and vertical cylinders, both turned about the vertical
//! axis), ray intersection, and a bounding-volume hierarchy over them.
//!
//! World frame: `z` up, floor at `z = 0`. Rendering works in `f32`: at indoor
//! ranges (< 20 m) its relative precision (6e-8) is far below the depth PNG step.

use super::texture::Material;
use nalgebra::Vector3;

/// A 3-vector of `f32`.
pub type V3 = Vector3<f32>;

/// Shape of a [`Solid`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// A box with half extents `half`.
    Box,
    /// A vertical cylinder of radius `half.x` and half height `half.z`.
    Cylinder,
}

/// A labelled, textured primitive. Its local frame is the world frame turned by
/// the yaw `(cos, sin)` about `z` around `center`; local `+y` is its "front".
#[derive(Debug, Clone)]
pub struct Solid {
    /// Box or vertical cylinder.
    pub shape: Shape,
    /// Centre in the world frame, metres.
    pub center: V3,
    /// Half extents along the local axes, metres (a cylinder: radius `x`, half height `z`).
    pub half: V3,
    /// Cosine of the yaw about `z`.
    pub cos: f32,
    /// Sine of the yaw about `z`.
    pub sin: f32,
    /// NYU40 label (0-based).
    pub label: u8,
    /// Surface appearance (material and its colours).
    pub material: Material,
    /// Per-solid texture variation.
    pub seed: u32,
}

/// Face of a hit: `2 * axis + (1 if the positive side)`, 6 for a cylinder's side.
pub type Face = u8;

/// A ray `o + t d` (`d` need not be unit length) with its precomputed inverse.
#[derive(Debug, Clone, Copy)]
pub struct Ray {
    /// Origin.
    pub o: V3,
    /// Direction (not necessarily unit length).
    pub d: V3,
    /// Component-wise inverse of `d`.
    pub inv: V3,
}

impl Ray {
    /// A ray from `o` along `d`, its inverse direction precomputed.
    pub fn new(o: V3, d: V3) -> Self {
        Ray {
            o,
            d,
            inv: V3::new(1.0 / d.x, 1.0 / d.y, 1.0 / d.z),
        }
    }
}

/// The nearest intersection along a ray.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    /// Ray parameter of the hit: the point is `o + t d`.
    pub t: f32,
    /// Index of the solid hit.
    pub solid: u32,
    /// Face hit (see [`Face`]).
    pub face: Face,
    /// Hit point in the solid's local frame, relative to its centre.
    pub local: V3,
}

impl Solid {
    /// An axis-aligned box from its two corners.
    pub fn aabb(min: V3, max: V3, label: u8, material: Material) -> Self {
        Solid {
            shape: Shape::Box,
            center: (min + max) * 0.5,
            half: (max - min) * 0.5,
            cos: 1.0,
            sin: 0.0,
            label,
            material,
            seed: 0,
        }
    }

    /// World direction of a local vector.
    #[inline]
    pub fn to_world(&self, v: V3) -> V3 {
        V3::new(
            self.cos * v.x - self.sin * v.y,
            self.sin * v.x + self.cos * v.y,
            v.z,
        )
    }

    /// Local direction of a world vector.
    #[inline]
    pub fn to_local(&self, v: V3) -> V3 {
        V3::new(
            self.cos * v.x + self.sin * v.y,
            -self.sin * v.x + self.cos * v.y,
            v.z,
        )
    }

    /// World-space bounds.
    pub fn bounds(&self) -> (V3, V3) {
        let e = match self.shape {
            Shape::Box => V3::new(
                self.cos.abs() * self.half.x + self.sin.abs() * self.half.y,
                self.sin.abs() * self.half.x + self.cos.abs() * self.half.y,
                self.half.z,
            ),
            Shape::Cylinder => V3::new(self.half.x, self.half.x, self.half.z),
        };
        (self.center - e, self.center + e)
    }

    /// Local outward normal of a face at a local point.
    pub fn local_normal(&self, face: Face, local: &V3) -> V3 {
        if face == 6 {
            return V3::new(local.x, local.y, 0.0).normalize();
        }
        let mut n = V3::zeros();
        n[(face / 2) as usize] = if face % 2 == 1 { 1.0 } else { -1.0 };
        n
    }

    /// Entering intersection with `t` in `(tmin, tmax)`: distance, local face
    /// and local hit point.
    pub fn intersect(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<(f32, Face, V3)> {
        Prim::new(self, 0).intersect(ray, tmin, tmax)
    }
}

/// The geometry of a solid in the compact form the ray caster works on.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Prim {
    center: V3,
    half: V3,
    /// World-space half extents.
    ext: V3,
    cos: f32,
    sin: f32,
    /// [`Prim::ALIGNED`] box (yaw a multiple of 90 degrees), rotated box or cylinder.
    kind: u8,
    /// Index of the solid.
    pub id: u32,
}

impl Prim {
    const ALIGNED: u8 = 0;
    const ROTATED: u8 = 1;
    const CYLINDER: u8 = 2;

    /// The compact form of solid `s`, with index `id`.
    pub fn new(s: &Solid, id: u32) -> Self {
        let (min, max) = s.bounds();
        let quarter = (s.cos == 0.0 || s.sin == 0.0) && (s.cos.abs() == 1.0 || s.sin.abs() == 1.0);
        Prim {
            center: s.center,
            half: s.half,
            ext: (max - min) * 0.5,
            cos: s.cos,
            sin: s.sin,
            kind: match s.shape {
                Shape::Cylinder => Self::CYLINDER,
                Shape::Box if quarter => Self::ALIGNED,
                Shape::Box => Self::ROTATED,
            },
            id,
        }
    }

    #[inline]
    fn local(&self, v: V3) -> V3 {
        V3::new(
            self.cos * v.x + self.sin * v.y,
            -self.sin * v.x + self.cos * v.y,
            v.z,
        )
    }

    /// Entering intersection with `t` in `(tmin, tmax)`.
    #[inline]
    pub fn intersect(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<(f32, Face, V3)> {
        if self.kind == Self::ALIGNED {
            // Slab test in world space, then the face in the local frame.
            let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
            let (mut axis, mut plus) = (0usize, false);
            for a in 0..3 {
                let lo = (self.center[a] - self.ext[a] - ray.o[a]) * ray.inv[a];
                let hi = (self.center[a] + self.ext[a] - ray.o[a]) * ray.inv[a];
                let (near, far, side) = if lo <= hi {
                    (lo, hi, false)
                } else {
                    (hi, lo, true)
                };
                if near > t0 {
                    t0 = near;
                    axis = a;
                    plus = side;
                }
                t1 = t1.min(far);
            }
            if t0 > t1 || t0 <= tmin || t0 >= tmax {
                return None;
            }
            let mut n = V3::zeros();
            n[axis] = if plus { 1.0 } else { -1.0 };
            let nl = self.local(n);
            let k = if nl.x != 0.0 {
                0
            } else if nl.y != 0.0 {
                1
            } else {
                2
            };
            let face = 2 * k as u8 + (nl[k] > 0.0) as u8;
            return Some((t0, face, self.local(ray.o + ray.d * t0 - self.center)));
        }
        let lo = self.local(ray.o - self.center);
        let ld = self.local(ray.d);
        let h = self.half;
        let (mut t0, mut t1, mut face) = (f32::NEG_INFINITY, f32::INFINITY, 0u8);
        let axes = if self.kind == Self::ROTATED {
            0..3
        } else {
            2..3
        };
        for a in axes {
            let inv = 1.0 / ld[a];
            let (mut ta, mut tb) = ((-h[a] - lo[a]) * inv, (h[a] - lo[a]) * inv);
            let mut f = 2 * a as u8;
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
                f += 1;
            }
            if ta > t0 {
                t0 = ta;
                face = f;
            }
            t1 = t1.min(tb);
        }
        if self.kind == Self::CYLINDER {
            let r = h.x;
            let a = ld.x * ld.x + ld.y * ld.y;
            let c = lo.x * lo.x + lo.y * lo.y - r * r;
            if a < 1e-20 {
                if c > 0.0 {
                    return None;
                }
            } else {
                let b = lo.x * ld.x + lo.y * ld.y;
                let disc = b * b - a * c;
                if disc < 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                let (ca, cb) = ((-b - s) / a, (-b + s) / a);
                if ca > t0 {
                    t0 = ca;
                    face = 6;
                }
                t1 = t1.min(cb);
            }
        }
        if t0 > t1 || t0 <= tmin || t0 >= tmax {
            return None;
        }
        Some((t0, face, lo + ld * t0))
    }
}

/// Ray / axis-aligned box slab test: entry distance if it is below `tmax`.
#[inline]
fn slab(ray: &Ray, min: &[f32; 3], max: &[f32; 3], tmax: f32) -> Option<f32> {
    let mut t0 = 0.0f32;
    let mut t1 = tmax;
    for a in 0..3 {
        let ta = (min[a] - ray.o[a]) * ray.inv[a];
        let tb = (max[a] - ray.o[a]) * ray.inv[a];
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t0 <= t1).then_some(t0)
}

#[derive(Debug, Clone)]
struct Node {
    min: [f32; 3],
    max: [f32; 3],
    /// Leaf: first index into `order`; inner node: index of the left child (the
    /// right child follows it).
    first: u32,
    /// Number of primitives of a leaf, 0 for an inner node.
    count: u32,
}

/// Bounding-volume hierarchy (surface-area heuristic) over a list of solids.
#[derive(Debug, Clone, Default)]
pub(crate) struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
    /// The primitives in leaf order.
    prims: Vec<Prim>,
}

fn area(min: &V3, max: &V3) -> f32 {
    let e = (max - min).map(|v| v.max(0.0));
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl Bvh {
    /// Builds the hierarchy.
    #[cfg(test)]
    pub fn build(solids: &[Solid]) -> Self {
        Self::build_offset(solids, 0)
    }

    /// Builds the hierarchy over `solids[skip..]` (hit ids still index `solids`).
    pub fn build_offset(all: &[Solid], skip: usize) -> Self {
        let solids = &all[skip.min(all.len())..];
        let bounds: Vec<(V3, V3)> = solids.iter().map(Solid::bounds).collect();
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * solids.len()),
            order: (0..solids.len() as u32).collect(),
            prims: Vec::new(),
        };
        if solids.is_empty() {
            return bvh;
        }
        bvh.nodes.push(Node {
            min: [0.0; 3],
            max: [0.0; 3],
            first: 0,
            count: 0,
        });
        bvh.split(0, 0, solids.len(), &bounds);
        bvh.prims = bvh
            .order
            .iter()
            .map(|&i| Prim::new(&solids[i as usize], i + skip as u32))
            .collect();
        bvh
    }

    fn split(&mut self, node: usize, lo: usize, hi: usize, bounds: &[(V3, V3)]) {
        let ids = &mut self.order[lo..hi];
        let (mut bmin, mut bmax) = (V3::repeat(f32::MAX), V3::repeat(f32::MIN));
        for &i in ids.iter() {
            bmin = bmin.inf(&bounds[i as usize].0);
            bmax = bmax.sup(&bounds[i as usize].1);
        }
        self.nodes[node].min = bmin.into();
        self.nodes[node].max = bmax.into();
        let n = hi - lo;
        let leaf = |s: &mut Self| {
            s.nodes[node].first = lo as u32;
            s.nodes[node].count = n as u32;
        };
        if n <= 2 {
            return leaf(self);
        }
        // Best SAH split over the three axes, primitives sorted by centroid.
        let centre = |i: u32| bounds[i as usize].0 + bounds[i as usize].1;
        let mut best: Option<(f32, usize, usize)> = None;
        let mut right_area = vec![0.0f32; n];
        for axis in 0..3 {
            ids.sort_by(|&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]).then(a.cmp(&b)));
            let (mut rmin, mut rmax) = (V3::repeat(f32::MAX), V3::repeat(f32::MIN));
            for k in (1..n).rev() {
                rmin = rmin.inf(&bounds[ids[k] as usize].0);
                rmax = rmax.sup(&bounds[ids[k] as usize].1);
                right_area[k] = area(&rmin, &rmax);
            }
            let (mut lmin, mut lmax) = (V3::repeat(f32::MAX), V3::repeat(f32::MIN));
            for k in 1..n {
                lmin = lmin.inf(&bounds[ids[k - 1] as usize].0);
                lmax = lmax.sup(&bounds[ids[k - 1] as usize].1);
                let cost = area(&lmin, &lmax) * k as f32 + right_area[k] * (n - k) as f32;
                if best.is_none_or(|b| cost < b.0) {
                    best = Some((cost, axis, k));
                }
            }
        }
        let Some((cost, axis, k)) = best else {
            return leaf(self);
        };
        let parent = area(&bmin, &bmax);
        if n <= 4 && cost >= parent * n as f32 {
            return leaf(self);
        }
        ids.sort_by(|&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]).then(a.cmp(&b)));
        let left = self.nodes.len();
        let blank = Node {
            min: [0.0; 3],
            max: [0.0; 3],
            first: 0,
            count: 0,
        };
        self.nodes.push(blank.clone());
        self.nodes.push(blank);
        self.nodes[node].first = left as u32;
        self.nodes[node].count = 0;
        self.split(left, lo, lo + k, bounds);
        self.split(left + 1, lo + k, hi, bounds);
    }

    /// The nearest hit with `t` in `(tmin, tmax)`.
    pub fn closest(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tbest = tmax;
        let mut stack = [0u32; 64];
        let mut sp = 0;
        if self.nodes.is_empty()
            || slab(ray, &self.nodes[0].min, &self.nodes[0].max, tbest).is_none()
        {
            return None;
        }
        stack[sp] = 0;
        sp += 1;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if node.count > 0 {
                for p in &self.prims[node.first as usize..(node.first + node.count) as usize] {
                    if let Some((t, face, local)) = p.intersect(ray, tmin, tbest) {
                        tbest = t;
                        best = Some(Hit {
                            t,
                            solid: p.id,
                            face,
                            local,
                        });
                    }
                }
                continue;
            }
            let (l, r) = (node.first as usize, node.first as usize + 1);
            let tl = slab(ray, &self.nodes[l].min, &self.nodes[l].max, tbest);
            let tr = slab(ray, &self.nodes[r].min, &self.nodes[r].max, tbest);
            match (tl, tr) {
                (Some(a), Some(b)) => {
                    // Push the farther child first so the nearer one is visited first.
                    let (near, far) = if a <= b { (l, r) } else { (r, l) };
                    stack[sp] = far as u32;
                    stack[sp + 1] = near as u32;
                    sp += 2;
                }
                (Some(_), None) => {
                    stack[sp] = l as u32;
                    sp += 1;
                }
                (None, Some(_)) => {
                    stack[sp] = r as u32;
                    sp += 1;
                }
                (None, None) => {}
            }
        }
        best
    }

    /// Whether anything lies on the ray with `t` in `(tmin, tmax)` (shadow rays).
    #[cfg(test)]
    pub fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        let mut stack = [0u32; 64];
        let mut sp = 0;
        if self.nodes.is_empty() {
            return false;
        }
        stack[sp] = 0;
        sp += 1;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if slab(ray, &node.min, &node.max, tmax).is_none() {
                continue;
            }
            if node.count > 0 {
                for p in &self.prims[node.first as usize..(node.first + node.count) as usize] {
                    if p.intersect(ray, tmin, tmax).is_some() {
                        return true;
                    }
                }
            } else {
                stack[sp] = node.first;
                stack[sp + 1] = node.first + 1;
                sp += 2;
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::texture::Material;

    fn solid(shape: Shape, c: V3, h: V3, yaw: f64) -> Solid {
        let (s, co) = crate::synth::detmath::sin_cos(yaw);
        Solid {
            shape,
            center: c,
            half: h,
            cos: co as f32,
            sin: s as f32,
            label: 0,
            material: Material::Plastic { color: [0.5; 3] },
            seed: 0,
        }
    }

    #[test]
    fn box_and_cylinder_hits() {
        let b = solid(
            Shape::Box,
            V3::new(5.0, 0.0, 0.0),
            V3::new(1.0, 1.0, 1.0),
            0.5,
        );
        let ray = Ray::new(V3::zeros(), V3::new(1.0, 0.0, 0.0));
        let (t, face, _) = b.intersect(&ray, 0.0, 100.0).unwrap();
        // A unit box turned by 0.5 rad: nearest corner-side distance along x.
        let expect = 5.0 - 1.0 / 0.5f32.cos();
        assert!((t - expect).abs() < 1e-5, "{t} {expect}");
        assert!(face < 4);
        let c = solid(
            Shape::Cylinder,
            V3::new(0.0, 3.0, 1.0),
            V3::new(0.5, 0.5, 1.0),
            0.0,
        );
        let up = Ray::new(V3::zeros(), V3::new(0.0, 1.0, 0.5));
        let (t, face, _) = c.intersect(&up, 0.0, 100.0).unwrap();
        assert!((t - 2.5).abs() < 1e-5 && face == 6, "{t} {face}");
        let top = Ray::new(V3::new(0.0, 3.0, 5.0), V3::new(0.0, 0.0, -1.0));
        let (t, face, _) = c.intersect(&top, 0.0, 100.0).unwrap();
        assert!((t - 3.0).abs() < 1e-5 && face == 5);
        assert!(c.intersect(&ray, 0.0, 100.0).is_none());
    }

    #[test]
    fn bvh_agrees_with_brute_force() {
        let mut solids = Vec::new();
        for i in 0..300u32 {
            let u = |k: u32| crate::synth::detmath::unit(crate::synth::detmath::hash2(i, k));
            let shape = if i % 5 == 0 {
                Shape::Cylinder
            } else {
                Shape::Box
            };
            solids.push(solid(
                shape,
                V3::new(u(0) * 10.0, u(1) * 10.0, u(2) * 3.0),
                V3::new(0.05 + u(3) * 0.5, 0.05 + u(4) * 0.5, 0.05 + u(5) * 0.5),
                if i % 3 == 0 {
                    (i % 4) as f64 * std::f64::consts::FRAC_PI_2
                } else {
                    u(6) as f64 * 6.0
                },
            ));
        }
        let bvh = Bvh::build(&solids);
        for k in 0..2000u32 {
            let u = |j: u32| crate::synth::detmath::unit(crate::synth::detmath::hash2(k + 999, j));
            let ray = Ray::new(
                V3::new(u(0) * 10.0, u(1) * 10.0, u(2) * 3.0),
                V3::new(u(3) - 0.5, u(4) - 0.5, u(5) - 0.5),
            );
            let brute = solids
                .iter()
                .enumerate()
                .filter_map(|(i, s)| s.intersect(&ray, 1e-4, 1e9).map(|h| (h.0, i)))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let fast = bvh.closest(&ray, 1e-4, 1e9);
            assert_eq!(brute.map(|b| b.1 as u32), fast.map(|h| h.solid));
            assert_eq!(brute.is_some(), bvh.occluded(&ray, 1e-4, 1e9));
        }
    }
}
