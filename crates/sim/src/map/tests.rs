//! The batched `rays` encoding against the one it replaced: one ray after
//! another, each stepped to its hit, on random maps, headings, stamps and
//! `keep`s.

use rand::{Rng, SeedableRng};

use super::*;

/// The `rays` encoding one ray at a time, each to its first obstacle or
/// wall (the form before the batched [`cast_rays`]).
fn cast_rays_one_by_one(
    map: &Reader,
    dirs: &[(f32, f32)],
    p: Vector,
    (c, sn): (f32, f32),
    s: &MapSpec,
    out: &mut [f32],
) {
    let (rays, range) = (s.rays, s.ray_range_m);
    let g = map.geo;
    let steps = (range * g.inv).ceil() as usize;
    let (ox, oy) = ((p.x - g.x0) * g.inv, (p.y - g.lo) * g.inv);
    let (occupied, unknown) = out.split_at_mut(rays);
    let span_x = (g.nx as u32) << FIX;
    let (top, ny) = (g.top as i32, g.ny);
    let dist =
        |j: usize| if j == steps { 1.0 } else { ((j as f32 + 0.5) * s.cell_m / range).min(1.0) };
    for (k, &(ca, sa)) in dirs.iter().enumerate() {
        let (dx, dy) = (c * ca - sn * sa, sn * ca + c * sa);
        let (mut fx, mut fy) = (fixed(ox + dx * 0.5), fixed(oy + dy * 0.5 + 1.0));
        let (sx, sy) = (fixed(dx), fixed(dy));
        let (mut hit, mut unseen) = (steps, steps);
        for j in 0..steps {
            let v = if (fx as u32) < span_x {
                let iy = (fy.max(0) >> FIX).min(top) as usize;
                map.cells[(fx >> FIX) as usize * ny + iy]
            } else {
                UNKNOWN
            };
            match map.cell(v) {
                Cell::Free => {}
                Cell::Unknown => unseen = unseen.min(j),
                Cell::Wall | Cell::Obstacle => {
                    hit = j;
                    unseen = unseen.min(j);
                    break;
                }
            }
            fx = fx.wrapping_add(sx);
            fy = fy.wrapping_add(sy);
        }
        occupied[k] = dist(hit);
        unknown[k] = dist(unseen);
    }
}

/// Trial `trial`'s maps for `spec` (one agent, a random lane, clock and
/// `keep`; cells drawn from `shares` of unknown, free, wall and sighted
/// out of their sum), a drone inside the grid or near it (a ray may start
/// outside along x) and its heading.
fn random_map(
    rng: &mut rand_pcg::Pcg64,
    spec: &MapSpec,
    trial: usize,
    shares: [u32; 4],
) -> (Maps, Vector, f32) {
    let (length, widest) = (rng.random_range(10.0..60.0), rng.random_range(4.0..16.0));
    let mut maps = Maps::new(spec, 1, length, 6.0, widest, 0.1);
    maps.keep = if trial.is_multiple_of(2) { 0 } else { rng.random_range(1..STAMPS - 2) };
    maps.clock[0] = rng.random_range(1..1000);
    let [unknown, free, wall, _] = shares;
    for c in &mut maps.cells {
        let r = rng.random_range(0..shares.iter().sum::<u32>());
        *c = if r < unknown {
            UNKNOWN
        } else if r < unknown + free {
            FREE
        } else if r < unknown + free + wall {
            WALL
        } else {
            HIT + rng.random_range(0..STAMPS) as u8
        };
    }
    let p = Vector::new(
        rng.random_range(-4.0..length + 4.0),
        rng.random_range(-widest / 2.0 - 1.0..widest / 2.0 + 1.0),
        3.0,
    );
    (maps, p, rng.random_range(-3.2..3.2))
}

#[test]
fn the_batched_rays_read_what_one_ray_after_another_reads() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    for trial in 0..400 {
        let rays = [36, 8, 17, 72][trial % 4];
        let spec = MapSpec {
            encoding: MapEncoding::Rays,
            rays,
            cell_m: [0.5, 0.25, 1.0][trial % 3],
            ray_range_m: rng.random_range(1.0..15.0),
            ..MapSpec::default()
        };
        // Mostly free, some unknown, a few walls and stamped sightings.
        let (maps, p, yaw) = random_map(&mut rng, &spec, trial, [4, 12, 1, 3]);
        let (mut batched, mut single) = (vec![0.0; 2 * rays], vec![0.0; 2 * rays]);
        let map = maps.reader(0);
        cast_rays(&map, &maps.dirs, p, (yaw.cos(), yaw.sin()), &spec, &mut batched);
        cast_rays_one_by_one(&map, &maps.dirs, p, (yaw.cos(), yaw.sin()), &spec, &mut single);
        assert_eq!(batched, single, "trial {trial}: at {p:?} heading {yaw}, keep {}", maps.keep);
    }
}

#[test]
fn the_batched_window_reads_what_cell_by_cell_reads() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    for trial in 0..300 {
        let window = [16, 5, 32, 9][trial % 4];
        let spec = MapSpec {
            encoding: MapEncoding::Grid,
            window,
            cell_m: [0.5, 0.25, 1.0][trial % 3],
            ..MapSpec::default()
        };
        let (maps, p, yaw) = random_map(&mut rng, &spec, trial, [3, 5, 1, 1]);
        let (c, sn) = (yaw.cos(), yaw.sin());
        let mut batched = vec![0.0; window * window];
        maps.encode(0, p, yaw, &mut batched);
        // Cell by cell through the map's own reading of a point.
        for (k, &got) in batched.iter().enumerate() {
            let (r, col) = (k / window, k % window);
            let f = (r as f32 - window as f32 / 4.0 + 0.5) * spec.cell_m;
            let l = (window as f32 / 2.0 - col as f32 - 0.5) * spec.cell_m;
            let want = match maps.at(0, p.x + c * f - sn * l, p.y + sn * f + c * l) {
                Cell::Unknown => 0.0,
                Cell::Free => 1.0 / 3.0,
                Cell::Wall => 2.0 / 3.0,
                Cell::Obstacle => 1.0,
            };
            assert_eq!(got, want, "trial {trial}: cell {k} at {p:?} heading {yaw}");
        }
    }
}
