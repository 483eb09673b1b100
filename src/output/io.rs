//! Particle snapshots: one HDF5 file per output time written by all ranks together
//! (parallel HDF5, collective hyperslab writes of flat arrays at offsets from an
//! exclusive scan of the local counts), and an XDMF file describing the time series
//! so that ParaView opens it directly.
//!
//! Every snapshot holds `id`, `rank` and `material` of each particle, the XDMF
//! `connectivity` (0..N-1), its `position` (N × 3, padded with zeros below 3D, as
//! ParaView expects), plus the fields the scene lists (`velocity` N × 3,
//! `displacement` N × 3, `stress` N × 9, the full 3 × 3 Cauchy stress: in 2D with the
//! plane-strain σ_zz, in 1D σ_xx only).
//!
//! Each file and the XDMF index also say what the numbers mean ([`Labels`]): the
//! material names behind the `material` index, the units, and the symmetry planes of
//! a scene that models part of a body.

use crate::input::scene::{Face, Field, Scene};
use crate::mpm::particles::{shape_bounds, Kinds, Particles};
use crate::physics::material::Material;
use decomposition::Communicator;
use hdf5::types::VarLenUnicode;
use hdf5_sys::{h5d, h5p, h5s, h5t};
use std::path::{Path, PathBuf};

/// What a snapshot could not do.
#[derive(Debug)]
pub struct IoError(pub String);

impl std::fmt::Display for IoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

pub(crate) fn h5err(path: &Path, e: hdf5::Error) -> IoError {
    IoError(format!("{}: {e}", path.display()))
}

/// One entry of the time series: a snapshot written at `step`, time `time`.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub step: u64,
    pub time: f64,
    pub particles: u64,
}

impl Entry {
    /// The snapshot's file name.
    pub fn file(&self) -> String {
        snapshot_name(self.step)
    }
}

/// The XDMF index of a run's snapshots.
pub const XDMF_NAME: &str = "particles.xmf";

/// `particles_NNNNNN.h5`.
pub fn snapshot_name(step: u64) -> String {
    format!("particles_{step:06}.h5")
}

/// Whether `name` is a snapshot's file name (`particles_` digits `.h5`).
pub fn is_snapshot_name(name: &str) -> bool {
    name.strip_prefix("particles_")
        .and_then(|r| r.strip_suffix(".h5"))
        .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
}

/// Rank 0 of a fresh run: delete the snapshots and the `particles.xmf` an earlier run
/// left in `out`. This run rewrites the series from step 0, so the old files would be
/// orphans that the new `particles.xmf` does not list, mixed in with the new ones
/// under the same name pattern (a script globbing `particles_*.h5` read both runs).
/// Checkpoints are not touched (see `checkpoint::Lineage`). Returns how many
/// snapshots went.
pub fn remove_old_snapshots(out: &Path) -> Result<usize, String> {
    let mut gone = 0;
    let entries = std::fs::read_dir(out).map_err(|e| format!("{}: {e}", out.display()))?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let snapshot = is_snapshot_name(&name);
        if snapshot || name == XDMF_NAME {
            match std::fs::remove_file(e.path()) {
                Ok(()) => gone += usize::from(snapshot),
                Err(err) if err.kind() == std::io::ErrorKind::NotFound => {}
                Err(err) => return Err(format!("{}: {err}", e.path().display())),
            }
        }
    }
    Ok(gone)
}

/// What a run's snapshot numbers mean (the same for every snapshot of the run).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Labels {
    /// The scene's material names, by the `material` index.
    pub materials: Vec<String>,
    /// `dimensionless` for benchmark scenes (exact solutions in unit-free parameters),
    /// `SI` for the others.
    pub units: String,
    /// The slip faces that cut a body, e.g. `x = 0, y = 0` (a quarter of the Taylor
    /// bar); `None` if no face cuts one.
    pub symmetry_planes: Option<String>,
}

impl Labels {
    /// The labels of a validated scene.
    pub fn of<const D: usize>(scene: &Scene) -> Self {
        let g = &scene.grid;
        let mut planes = Vec::new();
        for a in 0..D {
            // The test that lets a slip face cut a body in scene validation.
            let tol = 1e-12 * (g.upper[a] - g.lower[a]);
            let (lo, hi) = scene.bodies.iter().fold((false, false), |(lo, hi), b| {
                let (blo, bhi) = shape_bounds::<D>(&b.shape);
                (
                    lo || blo[a] < g.lower[a] - tol,
                    hi || bhi[a] > g.upper[a] + tol,
                )
            });
            for (cut, upper, at) in [(lo, false, g.lower[a]), (hi, true, g.upper[a])] {
                if cut && g.boundary.face(a, upper) == Face::Slip {
                    planes.push(format!("{} = {at}", ["x", "y", "z"][a]));
                }
            }
        }
        Self {
            materials: scene.materials.iter().map(|m| m.name.clone()).collect(),
            units: if scene.benchmark.is_some() {
                "dimensionless"
            } else {
                "SI"
            }
            .into(),
            symmetry_planes: (!planes.is_empty()).then(|| planes.join(", ")),
        }
    }

    /// The symmetry note stored with the snapshots.
    pub fn symmetry_note(&self) -> Option<String> {
        self.symmetry_planes.as_ref().map(|p| {
            format!(
                "{p}: slip faces that cut the bodies are symmetry planes; the particles are the part inside the grid (mirror them about the planes for the whole)"
            )
        })
    }
}

/// Writes snapshots and keeps the XDMF index of those written.
pub struct Snapshots {
    out: PathBuf,
    fields: Vec<Field>,
    labels: Labels,
    entries: Vec<Entry>,
    /// Flat staging buffer, reused between fields and snapshots.
    buf: Vec<f64>,
    ibuf: Vec<i64>,
}

impl Snapshots {
    pub fn new(out: &Path, fields: &[Field], labels: Labels) -> Self {
        let mut f = fields.to_vec();
        f.dedup();
        Self {
            out: out.to_path_buf(),
            fields: f,
            labels,
            entries: Vec::new(),
            buf: Vec::new(),
            ibuf: Vec::new(),
        }
    }

    /// The snapshots written so far (those of earlier runs too, after a restart).
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }

    /// Continue the time series of an earlier run (restart): these snapshots are listed
    /// in the XDMF index before the ones written from now on.
    pub fn set_entries(&mut self, entries: Vec<Entry>) {
        self.entries = entries;
    }

    /// Collective: write the particles of every rank at `step`, time `t`, then (rank 0)
    /// rewrite the XDMF index. `materials` (per kind of `kinds`) derive the stress
    /// components the particles do not store (plane strain σ_zz); `null` is each
    /// particle's `null_velocity` (empty unless the fields list it).
    pub fn write<const D: usize>(
        &mut self,
        comm: &dyn Communicator,
        parts: &Particles<D>,
        (kinds, materials): (&Kinds, &[Material]),
        null: &[nalgebra::SVector<f64, D>],
        (step, t): (u64, f64),
    ) -> Result<(), IoError> {
        let path = self.out.join(snapshot_name(step));
        let n = parts.len() as u64;
        let offset = comm.exclusive_scan_u64(n);
        let mut tot = [n];
        comm.sum_u64(&mut tot);
        let total = tot[0];
        let file = create(comm, &path)?;
        let written = self.datasets(
            comm,
            &file,
            &path,
            (parts, null),
            (kinds, materials),
            (step, t),
            offset,
            total,
        );
        close(comm, file, &path, written)?;
        // A restarted run may write a step again: replace its entry.
        self.entries.retain(|e| e.step < step);
        self.entries.push(Entry {
            step,
            time: t,
            particles: total,
        });
        let xdmf = if comm.rank() == 0 {
            self.write_xdmf().err()
        } else {
            None
        };
        // Rank 0 alone writes the index: let every rank know if that failed.
        if comm.any(xdmf.is_some()) {
            return Err(
                xdmf.unwrap_or_else(|| IoError("writing particles.xmf failed on rank 0".into()))
            );
        }
        Ok(())
    }

    /// The attributes and datasets of a snapshot, in lock-step over all ranks.
    #[allow(clippy::too_many_arguments)]
    fn datasets<const D: usize>(
        &mut self,
        comm: &dyn Communicator,
        file: &hdf5::File,
        path: &Path,
        (parts, null): (&Particles<D>, &[nalgebra::SVector<f64, D>]),
        (kinds, materials): (&Kinds, &[Material]),
        (step, t): (u64, f64),
        offset: u64,
        total: u64,
    ) -> Result<(), IoError> {
        let n = parts.len() as u64;
        let a = file
            .new_attr::<f64>()
            .create("time")
            .and_then(|a| a.write_scalar(&t))
            .and_then(|_| file.new_attr::<u64>().create("step"))
            .and_then(|a| a.write_scalar(&step))
            .and_then(|_| file.new_attr::<u64>().create("dim"))
            .and_then(|a| a.write_scalar(&(D as u64)));
        lockstep(comm, a.map_err(|e| h5err(path, e)))?;

        let w = Writer {
            comm,
            file,
            path,
            offset,
            count: n,
            total,
        };
        let ibuf = &mut self.ibuf;
        w.blocks("id", 0, ibuf, |r, b| {
            b.extend(parts.id[r].iter().map(|&i| i as i64))
        })?;
        let rank = comm.rank() as i64;
        w.blocks("rank", 0, ibuf, |r, b| b.resize(r.len(), rank))?;
        w.blocks("material", 0, ibuf, |r, b| {
            b.extend(
                parts.kind[r]
                    .iter()
                    .map(|&k| i64::from(kinds.material[k as usize])),
            )
        })?;
        // What the numbers mean: the names behind `material`, units, symmetry planes.
        lockstep(comm, self.write_labels(file).map_err(|e| h5err(path, e)))?;
        // The XDMF topology's connectivity (0..N-1, one vertex per particle): the
        // Xdmf3 readers, ParaView's default for `.xmf`, make no cells without it.
        let (buf, ibuf) = (&mut self.buf, &mut self.ibuf);
        w.blocks("connectivity", 0, ibuf, |r, b| {
            b.extend((offset + r.start as u64..offset + r.end as u64).map(|i| i as i64))
        })?;
        w.blocks("position", 3, buf, |r, b| {
            pad3(b, parts.x[r].iter().map(|x| x.as_slice()), D)
        })?;
        for &f in &self.fields {
            let (name, _, cols) = field_layout(f);
            match f {
                Field::Velocity => w.blocks(name, cols, buf, |r, b| {
                    pad3(b, parts.v[r].iter().map(|x| x.as_slice()), D)
                })?,
                Field::NullVelocity => w.blocks(name, cols, buf, |r, b| {
                    pad3(b, null[r].iter().map(|x| x.as_slice()), D)
                })?,
                Field::Displacement => w.blocks(name, cols, buf, |r, b| {
                    for p in r {
                        let u = if parts.x0.is_empty() {
                            nalgebra::SVector::<f64, D>::zeros()
                        } else {
                            parts.x[p] - parts.x0[p]
                        };
                        for a in 0..3 {
                            b.push(if a < D { u[a] } else { 0.0 });
                        }
                    }
                })?,
                Field::Stress => w.blocks(name, cols, buf, |r, b| {
                    for p in r {
                        let s = parts.stress3(p, materials);
                        // Row-major; the stress is symmetric anyway.
                        for i in 0..3 {
                            for j in 0..3 {
                                b.push(s[(i, j)]);
                            }
                        }
                    }
                })?,
                // Scalars, one value per particle (the scene only lists them when a
                // material carries them).
                Field::Volume => w.blocks(name, cols, buf, |r, b| {
                    b.extend(r.map(|p| parts.volume(p, &kinds.vol0)))
                })?,
                Field::PlasticStrain => w.floats(name, &parts.eps_p, cols)?,
                Field::Damage => w.floats(name, &parts.damage, cols)?,
            }
        }
        Ok(())
    }

    /// The [`Labels`] as string attributes: `material_names` (one per index), `units`
    /// and, if a slip face cuts a body, `symmetry`.
    fn write_labels(&self, file: &hdf5::File) -> hdf5::Result<()> {
        let text = |s: &str| {
            s.parse::<VarLenUnicode>()
                .map_err(|e| hdf5::Error::from(e.to_string()))
        };
        let names = self
            .labels
            .materials
            .iter()
            .map(|m| text(m))
            .collect::<hdf5::Result<Vec<_>>>()?;
        file.new_attr::<VarLenUnicode>()
            .shape([names.len()])
            .create("material_names")?
            .write(&names)?;
        let mut scalars = vec![("units", self.labels.units.clone())];
        if let Some(note) = self.labels.symmetry_note() {
            scalars.push(("symmetry", note));
        }
        for (name, value) in scalars {
            file.new_attr::<VarLenUnicode>()
                .create(name)?
                .write_scalar(&text(&value)?)?;
        }
        Ok(())
    }

    /// The same labels as XDMF `Information` elements of the time series.
    fn xdmf_information(&self) -> String {
        let l = &self.labels;
        let names = l
            .materials
            .iter()
            .enumerate()
            .map(|(i, m)| format!("{i}: {m}"))
            .collect::<Vec<_>>()
            .join("; ");
        let mut items = vec![("material_names", names), ("units", l.units.clone())];
        if let Some(note) = l.symmetry_note() {
            items.push(("symmetry", note));
        }
        items
            .iter()
            .map(|(k, v)| {
                format!(
                    "  <Information Name=\"{k}\" Value=\"{}\"/>\n",
                    xml_escape(v)
                )
            })
            .collect()
    }

    /// Rewrite `particles.xmf` (via a temporary file and a rename, so a reader never
    /// sees half of it).
    fn write_xdmf(&self) -> Result<(), IoError> {
        let mut x = String::from(
            "<?xml version=\"1.0\" ?>\n<!DOCTYPE Xdmf SYSTEM \"Xdmf.dtd\" []>\n<Xdmf Version=\"3.0\">\n <Domain>\n",
        );
        x += &self.xdmf_information();
        x += "  <Grid Name=\"particles\" GridType=\"Collection\" CollectionType=\"Temporal\">\n";
        for e in &self.entries {
            let n = e.particles;
            // `cols` 0: one value per particle.
            let item = |path: &str, cols: usize| {
                let dims = if cols == 0 {
                    n.to_string()
                } else {
                    format!("{n} {cols}")
                };
                format!(
                    "<DataItem Dimensions=\"{dims}\" NumberType=\"Float\" Precision=\"8\" Format=\"HDF\">{}:/{path}</DataItem>",
                    e.file()
                )
            };
            x += &format!(
                "   <Grid Name=\"{}\" GridType=\"Uniform\">\n    <Time Value=\"{:.17e}\"/>\n    <Topology TopologyType=\"Polyvertex\" NumberOfElements=\"{n}\" NodesPerElement=\"1\"><DataItem Dimensions=\"{n}\" NumberType=\"Int\" Precision=\"8\" Format=\"HDF\">{}:/connectivity</DataItem></Topology>\n    <Geometry GeometryType=\"XYZ\">{}</Geometry>\n",
                e.file(),
                e.time,
                e.file(),
                item("position", 3)
            );
            for (name, ty) in [("id", "Int"), ("rank", "Int"), ("material", "Int")] {
                x += &format!(
                    "    <Attribute Name=\"{name}\" AttributeType=\"Scalar\" Center=\"Node\"><DataItem Dimensions=\"{n}\" NumberType=\"{ty}\" Precision=\"8\" Format=\"HDF\">{}:/{name}</DataItem></Attribute>\n",
                    e.file()
                );
            }
            for f in &self.fields {
                let (name, ty, cols) = field_layout(*f);
                x += &format!(
                    "    <Attribute Name=\"{name}\" AttributeType=\"{ty}\" Center=\"Node\">{}</Attribute>\n",
                    item(name, cols)
                );
            }
            x += "   </Grid>\n";
        }
        x += "  </Grid>\n </Domain>\n</Xdmf>\n";
        let path = self.out.join(XDMF_NAME);
        let tmp = self.out.join(".particles.xmf.tmp");
        std::fs::write(&tmp, x)
            .and_then(|_| std::fs::rename(&tmp, &path))
            .map_err(|e| {
                // A full disk must not leave a half-written temporary file behind.
                let _ = std::fs::remove_file(&tmp);
                IoError(format!("{}: {e}", path.display()))
            })
    }
}

/// Text for an XML attribute value.
fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Each of `rows` (its first `d` values) padded with zeros to 3, appended to `buf`.
fn pad3<'a>(buf: &mut Vec<f64>, rows: impl Iterator<Item = &'a [f64]>, d: usize) {
    for r in rows {
        for a in 0..3 {
            buf.push(if a < d { r[a] } else { 0.0 });
        }
    }
}

/// Create a file: with the MPI-IO driver on an MPI communicator, plainly on one process.
pub(crate) fn create(comm: &dyn Communicator, path: &Path) -> Result<hdf5::File, IoError> {
    create_with_userblock(comm, path, 0)
}

/// [`create`] with `userblock` bytes at the start of the file that HDF5 leaves alone
/// (a power of two >= 512, or 0 for none).
pub(crate) fn create_with_userblock(
    comm: &dyn Communicator,
    path: &Path,
    userblock: u64,
) -> Result<hdf5::File, IoError> {
    let r = match comm.raw_mpi() {
        Some(raw) => hdf5::File::with_options()
            .with_fapl(|p| p.mpio(raw, None))
            .with_fcpl(|p| p.userblock(userblock))
            .create(path),
        None if comm.size() == 1 => hdf5::File::with_options()
            .with_fcpl(|p| p.userblock(userblock))
            .create(path),
        None => {
            return Err(IoError(format!(
                "{}: parallel output needs an MPI communicator",
                path.display()
            )))
        }
    };
    r.map_err(|e| h5err(path, e))
}

/// Collective: every rank's outcome of a step all ranks took, agreed over all ranks:
/// `Err` on every rank if it failed on any, so that all ranks leave the write
/// together. A rank where the step succeeded gets an empty message: the failure is
/// another rank's, whose message [`close`] reports.
pub(crate) fn lockstep<T>(comm: &dyn Communicator, r: Result<T, IoError>) -> Result<T, IoError> {
    if !comm.any(r.is_err()) {
        return r;
    }
    Err(r.err().unwrap_or_else(|| IoError(String::new())))
}

/// Collective: close a file every rank wrote, after `written` (each rank's outcome,
/// agreed with [`lockstep`]). On failure the partial file is deleted and rank 0's
/// message is the first failing rank's, with the operating system's reason.
///
/// HDF5 and MPI-IO report only that a write failed ("H5Dwrite failed"); the reason
/// (a full disk, a quota, a file size limit, an I/O error) is found by writing to the
/// file once more with plain file I/O. The partial file is then truncated before it is
/// closed: closing flushes HDF5's metadata, which fails on a full disk and leaves the
/// file open inside HDF5, whose clean-up at MPI_Finalize then crashes (HDF5 1.10).
/// The truncation frees the file's blocks, so the few kilobytes of metadata fit.
pub(crate) fn close(
    comm: &dyn Communicator,
    file: hdf5::File,
    path: &Path,
    written: Result<(), IoError>,
) -> Result<(), IoError> {
    let root = comm.rank() == 0;
    // Metadata is written when the file is flushed: a full disk may fail here first.
    let written = written.and_then(|()| {
        lockstep(
            comm,
            file.flush()
                .map_err(|e| IoError(format!("{}: flushing: {e}", path.display()))),
        )
    });
    let failed = written.is_err();
    let write_error = written.err().map(|e| e.0).filter(|m| !m.is_empty());
    let mut cause = None;
    if failed && root {
        cause = os_cause(path);
        let _ = std::fs::OpenOptions::new()
            .write(true)
            .open(path)
            .and_then(|f| f.set_len(0));
    }
    // No rank closes (and writes metadata) before rank 0 has made room.
    comm.any(false);
    let closed = file
        .close()
        .map_err(|e| format!("{}: closing: {e}", path.display()));
    // A file HDF5 failed to close stays open inside it (closing may still fail after
    // the truncation: with a file size limit, HDF5's final MPI_File_set_size to its
    // allocated size fails too), and HDF5's clean-up in MPI_Finalize then crashes on
    // it. Every rank learns of it, and the process ends without finalising.
    let close_failed = comm.any(closed.is_err());
    if close_failed {
        UNCLOSED.store(true, std::sync::atomic::Ordering::SeqCst);
    }
    // Both flags are agreed: every rank takes the same branches from here.
    if !failed && !close_failed {
        return Ok(());
    }
    if root {
        if cause.is_none() {
            cause = os_cause(path);
        }
        let _ = std::fs::remove_file(path);
    }
    // The first failure is the one to report: a failed write before the failed close
    // it causes.
    let m = agree(comm, write_error)
        .or_else(|| agree(comm, closed.err()))
        .unwrap_or_else(|| format!("{}: writing failed", path.display()));
    Err(IoError(match cause {
        Some(c) if root => format!("{m}: {c}"),
        _ => m,
    }))
}

/// Set when HDF5 failed to close a file (see [`close`]).
static UNCLOSED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Whether HDF5 failed to close a file: the process must then end without
/// `MPI_Finalize` and without HDF5's exit handler, both of which would crash on it.
pub fn unclosed_file() -> bool {
    UNCLOSED.load(std::sync::atomic::Ordering::SeqCst)
}

/// Why writing `path` fails, as the operating system says it: append 64 KiB and sync.
/// `None` if that works (the cause was something else, or has gone).
fn os_cause(path: &Path) -> Option<std::io::Error> {
    use std::io::Write;
    let probe = std::fs::OpenOptions::new()
        .append(true)
        .open(path)
        .and_then(|mut f| f.write_all(&[0u8; 1 << 16]).and_then(|_| f.sync_data()));
    probe.err()
}

/// A write that failed, past the process's file size limit (`ulimit -f`, as batch
/// systems set): the operating system's reason, which the probe of [`close`] may miss
/// (each rank writes its rows in place, so a refused block can lie well past the
/// file's end, and appending to it still works). `end` is where the write was to reach
/// in the file, at least.
fn past_size_limit(end: u64) -> Option<std::io::Error> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes the struct it is given and nothing else.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_FSIZE, &mut lim) } == 0;
    (ok && lim.rlim_cur != libc::RLIM_INFINITY && end > lim.rlim_cur)
        .then(|| std::io::Error::from_raw_os_error(libc::EFBIG))
}

/// Rows a block of [`Writer::blocks`] holds: 10.5 MB of a 3D checkpoint's
/// table, large enough that the writes stay few (16 for a rank of a million
/// particles).
pub(crate) const BLOCK_ROWS: usize = 1 << 16;

/// Collective writes of this rank's rows `[offset, offset + count)` of datasets with
/// `total` rows. Every dataset ends with an agreement over all ranks ([`lockstep`]):
/// with collective MPI-IO only the aggregating ranks touch the disk, so a full disk
/// fails the write on some ranks and not on others, and a rank that went on alone
/// would wait for ever in the next collective call.
#[derive(Clone, Copy)]
pub(crate) struct Writer<'a> {
    pub comm: &'a dyn Communicator,
    pub file: &'a hdf5::File,
    pub path: &'a Path,
    pub offset: u64,
    pub count: u64,
    pub total: u64,
}

/// The element types [`Writer`] stores, each with the HDF5 native type that describes
/// it in memory. Sealed (implemented here only): `H5Dwrite` reads the buffer as
/// `mem_type`, so a type id that does not describe `Self` exactly (another size, or a
/// variable-length type whose elements are pointers) would read memory it must not.
pub(crate) trait Native: Copy + hdf5::H5Type + sealed::Sealed {
    /// The HDF5 native memory type of `Self`.
    fn mem_type() -> hdf5_sys::h5i::hid_t;
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for u8 {}
    impl Sealed for u64 {}
    impl Sealed for i64 {}
    impl Sealed for f64 {}
}

impl Native for u8 {
    fn mem_type() -> hdf5_sys::h5i::hid_t {
        *h5t::H5T_NATIVE_UINT8
    }
}

impl Native for u64 {
    fn mem_type() -> hdf5_sys::h5i::hid_t {
        *h5t::H5T_NATIVE_UINT64
    }
}

impl Native for i64 {
    fn mem_type() -> hdf5_sys::h5i::hid_t {
        *h5t::H5T_NATIVE_INT64
    }
}

impl Native for f64 {
    fn mem_type() -> hdf5_sys::h5i::hid_t {
        *h5t::H5T_NATIVE_DOUBLE
    }
}

impl Writer<'_> {
    pub fn u64s(&self, name: &str, data: &[u64]) -> Result<(), IoError> {
        self.dataset(name, data, 0)
    }

    pub fn bytes(&self, name: &str, data: &[u8]) -> Result<(), IoError> {
        self.dataset(name, data, 0)
    }

    /// A dataset of `total × cols` values, or of `total` values if `cols == 0`.
    pub fn floats(&self, name: &str, data: &[f64], cols: usize) -> Result<(), IoError> {
        self.dataset(name, data, cols)
    }

    /// The dataset `name` of `total × cols` values (`total` if `cols == 0`), this
    /// rank's rows written [`BLOCK_ROWS`] at a time from `fill(rows, buf)`, which puts
    /// this rank's rows `rows` into `buf` (cleared first). The buffer holds one block,
    /// not all rows: a checkpoint's table is 160 bytes per particle in 3D, more than
    /// the particles' own state (154), and a snapshot's stress 72. Every rank takes part
    /// in as many collective writes as the rank with the most rows (empty selections
    /// past its own), and all agree after each. The same file as one write of all rows.
    pub fn blocks<T: Native>(
        &self,
        name: &str,
        cols: usize,
        buf: &mut Vec<T>,
        mut fill: impl FnMut(std::ops::Range<usize>, &mut Vec<T>),
    ) -> Result<(), IoError> {
        let blocks = |rows: u64| rows.div_ceil(BLOCK_ROWS as u64);
        let mut most = [blocks(self.count) as f64];
        self.comm.max_f64(&mut most);
        let err = |m: String| IoError(format!("{}: writing `{name}`: {m}", self.path.display()));
        let shape = if cols == 0 {
            vec![self.total as usize]
        } else {
            vec![self.total as usize, cols]
        };
        let ds = self
            .file
            .new_dataset::<T>()
            .shape(shape)
            .create(name)
            .map_err(|e| err(e.to_string()));
        let ds = lockstep(self.comm, ds)?;
        for b in 0..most[0] as u64 {
            let first = (b * BLOCK_ROWS as u64).min(self.count);
            let rows = (self.count - first).min(BLOCK_ROWS as u64);
            buf.clear();
            fill(first as usize..(first + rows) as usize, buf);
            let block = Writer {
                offset: self.offset + first,
                count: rows,
                ..*self
            };
            let row = (cols.max(1) * std::mem::size_of::<T>()) as u64;
            let written = block.raw_write(&ds, buf, cols).map_err(|m| {
                match past_size_limit((block.offset + block.count) * row) {
                    Some(c) => err(format!("{m}: {c}")),
                    None => err(m),
                }
            });
            lockstep(self.comm, written)?;
        }
        Ok(())
    }

    /// Create the dataset `name` of `total × cols` values (`total` if `cols == 0`),
    /// write this rank's rows from `data`, then agree with the other ranks on the
    /// outcome.
    fn dataset<T: Native>(&self, name: &str, data: &[T], cols: usize) -> Result<(), IoError> {
        let shape = if cols == 0 {
            vec![self.total as usize]
        } else {
            vec![self.total as usize, cols]
        };
        let r = self
            .file
            .new_dataset::<T>()
            .shape(shape)
            .create(name)
            .map_err(|e| e.to_string())
            .and_then(|ds| self.raw_write(&ds, data, cols))
            .map_err(|m| IoError(format!("{}: writing `{name}`: {m}", self.path.display())));
        lockstep(self.comm, r)
    }

    /// Collective (with MPI-IO) write of this rank's rows `[offset, offset + count)`
    /// from `data`; `cols == 0` means a 1-D dataset. A rank without rows takes part with
    /// an empty selection. Every HDF5 call's result is checked: a failure names the
    /// call.
    fn raw_write<T: Native>(
        &self,
        ds: &hdf5::Dataset,
        data: &[T],
        cols: usize,
    ) -> Result<(), String> {
        let (start, count): (Vec<u64>, Vec<u64>) = if cols == 0 {
            (vec![self.offset], vec![self.count])
        } else {
            (vec![self.offset, 0], vec![self.count, cols as u64])
        };
        // HDF5 reads `count × max(cols, 1)` values of `T` from the buffer.
        let values = self.count as usize * cols.max(1);
        if data.len() != values {
            return Err(format!("{} values for a selection of {values}", data.len()));
        }
        let id = ds.id();
        let ty = T::mem_type();
        // `create` opens files with MPI-IO exactly when there is an MPI communicator
        // (asking the file instead duplicates the communicator, a collective call).
        let parallel = self.comm.raw_mpi().is_some();
        hdf5::sync::sync(|| {
            // SAFETY: `ty` describes `T` (the sealed `Native`), and its size is checked
            // as well, so the `values` elements HDF5 reads from `data` (checked above)
            // lie inside it; `start` and `count` have the dataset's rank and outlive the
            // calls that read them; every other id is created here and closed by its
            // `Owned` guard.
            unsafe {
                let size = h5t::H5Tget_size(ty);
                if size == 0 {
                    return Err("H5Tget_size failed".into());
                }
                if size != std::mem::size_of::<T>() {
                    return Err(format!(
                        "memory type of {size} bytes for values of {}",
                        std::mem::size_of::<T>()
                    ));
                }
                let fspace = Owned::new(h5d::H5Dget_space(id), h5s::H5Sclose, "H5Dget_space")?;
                let dxpl = Owned::new(
                    h5p::H5Pcreate(*h5p::H5P_CLS_DATASET_XFER),
                    h5p::H5Pclose,
                    "H5Pcreate",
                )?;
                if parallel {
                    let r =
                        h5p::H5Pset_dxpl_mpio(dxpl.0, h5p::H5FD_mpio_xfer_t::H5FD_MPIO_COLLECTIVE);
                    check(r, "H5Pset_dxpl_mpio")?;
                }
                let mspace = Owned::new(
                    h5s::H5Screate_simple(count.len() as i32, count.as_ptr(), std::ptr::null()),
                    h5s::H5Sclose,
                    "H5Screate_simple",
                )?;
                if self.count == 0 {
                    check(h5s::H5Sselect_none(fspace.0), "H5Sselect_none")?;
                    check(h5s::H5Sselect_none(mspace.0), "H5Sselect_none")?;
                } else {
                    let r = h5s::H5Sselect_hyperslab(
                        fspace.0,
                        h5s::H5S_seloper_t::H5S_SELECT_SET,
                        start.as_ptr(),
                        std::ptr::null(),
                        count.as_ptr(),
                        std::ptr::null(),
                    );
                    check(r, "H5Sselect_hyperslab")?;
                }
                let r = h5d::H5Dwrite(id, ty, mspace.0, fspace.0, dxpl.0, data.as_ptr().cast());
                check(r, "H5Dwrite")?;
                mspace.close("H5Sclose")?;
                dxpl.close("H5Pclose")?;
                fspace.close("H5Sclose")
            }
        })
    }
}

/// An HDF5 status (`herr_t`) as a result naming the call.
fn check(r: hdf5_sys::h5::herr_t, call: &str) -> Result<(), String> {
    if r < 0 {
        Err(format!("{call} failed"))
    } else {
        Ok(())
    }
}

type CloseFn = unsafe extern "C" fn(hdf5_sys::h5i::hid_t) -> hdf5_sys::h5::herr_t;

/// An HDF5 id, closed with its close function: by [`Owned::close`], which reports a
/// failure, or when dropped on the way out of an error, which is already reported.
struct Owned(hdf5_sys::h5i::hid_t, CloseFn);

impl Owned {
    /// The id an HDF5 call `call` returned, or its failure (a negative id).
    fn new(id: hdf5_sys::h5i::hid_t, close: CloseFn, call: &str) -> Result<Self, String> {
        if id < 0 {
            Err(format!("{call} failed"))
        } else {
            Ok(Self(id, close))
        }
    }

    /// Close the id now; `call` names the close function in the error.
    fn close(mut self, call: &str) -> Result<(), String> {
        let id = std::mem::replace(&mut self.0, -1);
        // SAFETY: as in `drop`; the guard no longer holds the id, so it is closed once.
        check(unsafe { (self.1)(id) }, call)
    }
}

impl Drop for Owned {
    fn drop(&mut self) {
        if self.0 >= 0 {
            // SAFETY: the id was returned by the HDF5 call that created it, is owned by
            // this guard alone, and its close function is the one for its kind.
            unsafe { (self.1)(self.0) };
        }
    }
}

/// Collective: `Some(message)` on every rank if any rank has an error; the message is
/// the first failing rank's own on rank 0, a pointer to it elsewhere.
pub fn agree(comm: &dyn Communicator, mine: Option<String>) -> Option<String> {
    if !comm.any(mine.is_some()) {
        return None;
    }
    let all = comm.gather_bytes(mine.as_deref().unwrap_or("").as_bytes());
    if comm.rank() == 0 {
        let (r, m) = all
            .iter()
            .enumerate()
            .find(|(_, m)| !m.is_empty())
            .expect("some rank failed");
        let m = String::from_utf8_lossy(m).into_owned();
        Some(if r == 0 { m } else { format!("rank {r}: {m}") })
    } else {
        Some(mine.unwrap_or_else(|| "failed on another rank".into()))
    }
}

/// How a snapshot field is stored, for the writer and the XDMF index alike: its
/// dataset name, XDMF attribute type and values per particle (0: one, a plain vector).
fn field_layout(f: Field) -> (&'static str, &'static str, usize) {
    match f {
        Field::Velocity => ("velocity", "Vector", 3),
        Field::NullVelocity => ("null_velocity", "Vector", 3),
        Field::Displacement => ("displacement", "Vector", 3),
        Field::Stress => ("stress", "Tensor", 9),
        Field::PlasticStrain => ("plastic_strain", "Scalar", 0),
        Field::Damage => ("damage", "Scalar", 0),
        Field::Volume => ("volume", "Scalar", 0),
    }
}
