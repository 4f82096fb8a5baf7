//! `harmap bench`: the figures the issues ask for, on this machine.

use std::path::PathBuf;
use std::time::Instant;

use harmap::grid::MemBudget;
use harmap::input::InputOptions;
use harmap::pipeline::{voxelize_new_run, Source};
use harmap::voxelize::VoxelizeOptions;

use super::progress::Bars;
use super::solve::CycleArg;
use super::{Global, UsageError};

/// Measure a stage: time, voxels per second and peak resident memory.
///
/// `harmap bench solve` builds the standard problem (an N^3 grid, the ball of radius
/// 0.45 N, phi = 0 within 2 voxels of the center) and solves it with the default
/// multigrid (--cycle fmg: full multigrid to the discretization error; --cycle v:
/// V-cycles to rtol 1e-6), from the labels to a stored phi: seconds, cycles (the
/// coarse phase of fmg is one), fine-grid sweep equivalents, voxel updates per second,
/// the relative residual and peak memory.
///
/// `harmap bench trace` solves the same problem (untimed; a solved run kept in --dir is
/// reused) and times the whole trace of --sample boundary seeds, reading u included:
/// streamlines per second, RK45 steps per streamline, the share that reached the center.
///
/// `harmap bench map` solves the same problem (timed, or a solved run kept in --dir is
/// reused with its recorded solve time) and times the default map: the map's seconds
/// next to the solve's, voxels per second, rounds over the blocks.
///
/// `harmap bench voxelize` voxelizes a mesh (default: the armadillo of the project's
/// test data when it is found, else the built-in starfish) at each --n and prints one
/// line per size. Peak memory is the process's high-water mark (VmHWM), so run one size
/// per process for a clean figure.
///
/// Examples:
///   harmap bench voxelize --n 256 --n 512 --input armadillo.obj.gz
///   harmap bench solve --n 256
///   harmap bench solve --n 256 --cycle v
///   harmap bench solve --n 512 --mem 256MiB
///   harmap bench solve --n 512 --mem 256MiB --dir /scratch/b --keep
///   harmap bench trace --n 256 --sample 50000
///   harmap bench trace --n 512 --mem 256MiB --dir /scratch/b --keep
///   harmap bench map --n 256
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The stage to measure.
    #[arg(value_enum)]
    pub stage: Stage,
    /// Grid resolution(s) to measure.
    #[arg(long, value_name = "N", default_values_t = [256u64, 512])]
    pub n: Vec<u64>,
    /// Memory budget.
    #[arg(long, value_name = "SIZE", default_value = "1GiB")]
    pub mem: MemBudget,
    /// Mesh to voxelize.
    #[arg(long)]
    pub input: Option<PathBuf>,
    /// Where to put the temporary runs (default: the system temp directory).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Keep the runs (`bench-solve-N.harmap`, with phi) in --dir instead of removing
    /// them, e.g. to compare budgets or resume runs against them. `bench trace` reuses a
    /// solved run it finds there.
    #[arg(long, requires = "dir")]
    pub keep: bool,
    /// Multigrid's cycle for the solve (see `harmap solve --help`).
    #[arg(long, value_enum, default_value_t = CycleArg::from(harmap::solve::SolveOptions::default().cycle.kind))]
    pub cycle: CycleArg,
    /// Seeds `bench trace` traces (a deterministic subset of the boundary voxels).
    #[arg(long, value_name = "N", default_value_t = 50_000)]
    pub sample: u64,
}

/// Stages `bench` can measure.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Stage {
    /// Mesh -> labels.
    Voxelize,
    /// Labels -> phi, multigrid, on the standard problem (ball of radius 0.45 N, sink of
    /// radius 2).
    Solve,
    /// The whole `harmap trace` (reading u included) of --sample boundary seeds on the
    /// solved standard problem.
    Trace,
    /// The default (upwind) `harmap map` of the solved standard problem, next to the
    /// time of its solve.
    Map,
}

/// Peak resident set of this process so far, bytes (Linux; 0 elsewhere).
pub fn peak_rss() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map_or(0, |kib| kib * 1024)
}

/// Run `harmap bench`.
#[allow(clippy::many_single_char_names)] // n, the grid size, as the benchmark tables name it
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    match a.stage {
        Stage::Solve => return bench_solve(a, g),
        Stage::Trace => return bench_trace(a, g),
        Stage::Map => return bench_map(a, g),
        Stage::Voxelize => {}
    }
    let input = a.input.clone().or_else(|| {
        [
            "../shared/data/meshes/armadillo.obj.gz",
            "../../shared/data/meshes/armadillo.obj.gz",
        ]
        .iter()
        .map(PathBuf::from)
        .find(|p| p.exists())
    });
    if let Some(p) = &input {
        if !p.exists() {
            return Err(UsageError(format!("{}: no such file", p.display())).into());
        }
    }
    let iopts = InputOptions::default();
    let source = input
        .as_ref()
        .map_or(Source::Starfish, |p| Source::File(p, &iopts));
    let name = input
        .as_ref()
        .map_or("built-in starfish".to_owned(), |p| p.display().to_string());
    println!(
        "harmap bench voxelize: {name}, --mem {}, {} threads",
        a.mem,
        rayon::current_num_threads()
    );
    println!(
        "{:>6} {:>16} {:>10} {:>14} {:>12}",
        "N", "grid (x*y*z)", "seconds", "voxels/s", "peak RSS"
    );
    let bars = Bars::new(g);
    in_bench_dir(a.dir.as_ref(), |dir| {
        for &n in &a.n {
            let out = dir.join(format!("bench-{n}.harmap"));
            // Speed is measured whatever topology the shape has at this resolution.
            let opts = VoxelizeOptions {
                resolution: Some(n),
                mem: a.mem,
                allow_genus: true,
                ..VoxelizeOptions::default()
            };
            let t = Instant::now();
            let (_, r) = voxelize_new_run(&source, &opts, &out, true, &bars)?;
            let secs = t.elapsed().as_secs_f64();
            let s = r.grid.shape;
            println!(
                "{n:>6} {:>16} {secs:>10.3} {:>14.3e} {:>12}",
                format!("{}x{}x{}", s[2], s[1], s[0]),
                r.grid.num_voxels() as f64 / secs,
                harmap::grid::human(peak_rss())
            );
            std::fs::remove_dir_all(&out)?;
        }
        Ok(())
    })
}

/// `harmap bench solve`: the standard problem at each --n, from labels to a stored phi.
fn bench_solve(a: &Args, g: &Global) -> anyhow::Result<()> {
    use harmap::solve::solve;
    let opts = solve_options(a.mem, a.cycle);
    // On MPI ranks rank 0 prints (the rank lines after each row are per rank).
    let root = harmap::grid::world().is_root();
    if root {
        println!(
            "harmap bench solve: standard ball (radius 0.45 N, sink radius 2), multigrid --cycle {}, --mem {}, {} threads{}",
            opts.cycle.kind.name(),
            a.mem,
            rayon::current_num_threads(),
            ranks_suffix()
        );
        println!(
            "{:>6} {:>9} {:>7} {:>8} {:>14} {:>10} {:>12}",
            "N", "seconds", "cycles", "sweeps", "updates/s", "residual", "peak RSS"
        );
    }
    let bars = Bars::new(g);
    let stop = std::sync::atomic::AtomicBool::new(false);
    in_bench_dir(a.dir.as_ref(), |dir| {
        for &n in &a.n {
            let out = dir.join(format!("bench-solve-{n}.harmap"));
            let run = standard_ball(n, a.mem, &out, &bars)?;
            let (t, sent) = (Instant::now(), harmap::grid::world().bytes_sent());
            let r = solve(&run, &opts, &stop, &bars)?;
            let secs = t.elapsed().as_secs_f64();
            if root {
                println!(
                    "{n:>6} {secs:>9.3} {:>7} {:>8.1} {:>14.3e} {:>10.2e} {:>12}",
                    r.iterations,
                    r.sweep_equivalents,
                    r.unknowns as f64 * r.sweep_equivalents / secs,
                    r.relative_residual,
                    harmap::grid::human(peak_rss())
                );
            }
            per_rank(t, sent)?;
            remove_unless_kept(a, &out)?;
        }
        Ok(())
    })
}

/// `harmap bench trace`: the standard problem at each --n, solved (not timed, or found
/// solved in --dir), then the whole trace of --sample boundary seeds, timed.
fn bench_trace(a: &Args, g: &Global) -> anyhow::Result<()> {
    use harmap::trace::{trace, TraceOptions};
    // On MPI ranks rank 0 prints (the rank lines after each row are per rank).
    let root = harmap::grid::world().is_root();
    if root {
        println!(
            "harmap bench trace: standard ball (radius 0.45 N, sink radius 2), {} boundary seeds, --mem {}, {} threads{}",
            a.sample,
            a.mem,
            rayon::current_num_threads(),
            ranks_suffix()
        );
        println!(
            "{:>6} {:>8} {:>9} {:>13} {:>11} {:>9} {:>12}",
            "N", "seeds", "seconds", "streamlines/s", "steps/line", "reached", "peak RSS"
        );
    }
    let bars = Bars::new(g);
    in_bench_dir(a.dir.as_ref(), |dir| {
        for &n in &a.n {
            let out = dir.join(format!("bench-solve-{n}.harmap"));
            let (run, _) = solved_ball(n, a.mem, &out, &bars)?;
            let opts = TraceOptions {
                sample: Some(a.sample),
                mem: a.mem,
                ..TraceOptions::default()
            };
            let (t, sent) = (Instant::now(), harmap::grid::world().bytes_sent());
            let r = trace(&run, &opts, &bars)?;
            let secs = t.elapsed().as_secs_f64();
            if root {
                println!(
                    "{n:>6} {:>8} {secs:>9.3} {:>13.0} {:>11.1} {:>8.2}% {:>12}",
                    r.seeds,
                    r.seeds as f64 / secs,
                    r.mean_steps,
                    100.0 * r.reached_fraction,
                    harmap::grid::human(peak_rss())
                );
            }
            per_rank(t, sent)?;
            remove_unless_kept(a, &out)?;
        }
        Ok(())
    })
}

/// The solved standard problem at `out`: the run found there when it is solved, else a
/// new one, solved. With the solve's seconds (as recorded, for a run found solved).
fn solved_ball(
    n: u64,
    mem: MemBudget,
    out: &std::path::Path,
    bars: &Bars,
) -> anyhow::Result<(harmap::run::RunDir, f64)> {
    use harmap::run::RunDir;
    let found = RunDir::open(out)
        .ok()
        .filter(|r| r.has_image("u") && r.require_stage("solve").is_ok());
    if let Some(r) = found {
        let secs = harmap::run::stage_record(&r.attrs()?, "solve").map_or(f64::NAN, |s| s.seconds);
        return Ok((r, secs));
    }
    let run = standard_ball(n, mem, out, bars)?;
    let stop = std::sync::atomic::AtomicBool::new(false);
    let t = Instant::now();
    harmap::solve::solve(&run, &solve_options(mem, CycleArg::Fmg), &stop, bars)?;
    Ok((run, t.elapsed().as_secs_f64()))
}

/// `harmap bench map`: the standard problem at each --n, solved (timed, or found solved
/// in --dir with its recorded time), then the default (upwind) map, timed.
fn bench_map(a: &Args, g: &Global) -> anyhow::Result<()> {
    use harmap::map::{map, MapOptions};
    // On MPI ranks rank 0 prints (the rank lines after each row are per rank).
    let root = harmap::grid::world().is_root();
    if root {
        println!(
            "harmap bench map: standard ball (radius 0.45 N, sink radius 2), upwind map, --mem {}, {} threads{}",
            a.mem,
            rayon::current_num_threads(),
            ranks_suffix()
        );
        println!(
            "{:>6} {:>11} {:>9} {:>10} {:>11} {:>7} {:>12}",
            "N", "solve (s)", "map (s)", "map/solve", "voxels/s", "rounds", "peak RSS"
        );
    }
    let bars = Bars::new(g);
    in_bench_dir(a.dir.as_ref(), |dir| {
        for &n in &a.n {
            let out = dir.join(format!("bench-solve-{n}.harmap"));
            let (run, solve_secs) = solved_ball(n, a.mem, &out, &bars)?;
            let opts = MapOptions {
                mem: a.mem,
                ..MapOptions::default()
            };
            let (t, sent) = (Instant::now(), harmap::grid::world().bytes_sent());
            let r = map(&run, &opts, &bars)?;
            let secs = t.elapsed().as_secs_f64();
            let rounds = r.upwind.map_or(0, |u| u.rounds[0] + u.rounds[1]);
            if root {
                println!(
                    "{n:>6} {solve_secs:>11.3} {secs:>9.3} {:>10.2} {:>11.3e} {rounds:>7} {:>12}",
                    secs / solve_secs,
                    r.voxels as f64 / secs,
                    harmap::grid::human(peak_rss())
                );
            }
            per_rank(t, sent)?;
            remove_unless_kept(a, &out)?;
        }
        Ok(())
    })
}

/// The standard problem at `n` (ball of radius 0.45 n, sink radius 2, chunks 64^3) as a
/// new run at `out`.
fn standard_ball(
    n: u64,
    mem: MemBudget,
    out: &std::path::Path,
    bars: &Bars,
) -> anyhow::Result<harmap::run::RunDir> {
    let p = harmap::voxelize::StandardBall {
        n,
        sink_radius: 2.0,
        chunk: 64,
        mem,
    };
    // On MPI ranks rank 0 makes the run alone; the others open it.
    let w = harmap::grid::world();
    if w.is_root() {
        harmap::grid::solo(|| harmap::pipeline::standard_ball_run(&p, out, true, bars))?;
    }
    w.barrier()?;
    Ok(harmap::run::RunDir::open(out)?)
}

/// ", K MPI ranks" on K > 1 ranks, else nothing: the end of a benchmark's title.
fn ranks_suffix() -> String {
    match harmap::grid::world().parts() {
        1 => String::new(),
        n => format!(", {n} MPI ranks"),
    }
}

/// Remove the benchmark's run `out` unless --keep: on MPI ranks rank 0 alone, after
/// every rank is done with it.
fn remove_unless_kept(a: &Args, out: &std::path::Path) -> anyhow::Result<()> {
    let w = harmap::grid::world();
    w.barrier()?;
    if !a.keep && w.is_root() {
        std::fs::remove_dir_all(out)?;
    }
    Ok(())
}

/// On MPI ranks, each rank's seconds, bytes sent and peak resident memory since `t`
/// and `sent` (bytes sent before), printed by rank 0 one line a rank. One process:
/// nothing.
fn per_rank(t: Instant, sent: u64) -> anyhow::Result<()> {
    let w = harmap::grid::world();
    if w.parts() == 1 {
        return Ok(());
    }
    let mine = [
        t.elapsed().as_secs_f64(),
        (w.bytes_sent() - sent) as f64,
        peak_rss() as f64,
    ];
    let all = w.all_gather_bytes(mine.iter().flat_map(|v| v.to_le_bytes()).collect())?;
    if w.is_root() {
        for (k, b) in all.iter().enumerate() {
            let v: Vec<f64> = b
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
                .collect();
            println!(
                "{:>6} rank {k}: {:.3} s, sent {}, peak RSS {}",
                "",
                v[0],
                harmap::grid::human(v[1] as u64),
                harmap::grid::human(v[2] as u64)
            );
        }
    }
    Ok(())
}

/// The benchmarks' solve: multigrid defaults with `cycle`, no checkpoints.
fn solve_options(mem: MemBudget, cycle: CycleArg) -> harmap::solve::SolveOptions {
    use harmap::solve::{Cycle, CycleOptions};
    harmap::solve::SolveOptions {
        mem,
        cycle: CycleOptions {
            kind: match cycle {
                CycleArg::Fmg => Cycle::Fmg,
                CycleArg::V => Cycle::V,
            },
            ..CycleOptions::default()
        },
        checkpoint_every: 0.0,
        ..harmap::solve::SolveOptions::default()
    }
}

/// Run `f` in the directory for the benchmark's runs: the one given, or a new one in the
/// system temp directory, which is removed afterwards (a given one is the user's).
fn in_bench_dir(
    given: Option<&PathBuf>,
    f: impl FnOnce(&std::path::Path) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    if given.is_none() && harmap::grid::world().parts() > 1 {
        return Err(UsageError("on MPI ranks, give --dir: a folder every rank sees".into()).into());
    }
    let d = given.cloned().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("harmap-bench-{}", std::process::id()))
    });
    std::fs::create_dir_all(&d)?;
    let measured = f(&d);
    if given.is_none() {
        let _ = std::fs::remove_dir_all(&d);
    }
    measured
}
