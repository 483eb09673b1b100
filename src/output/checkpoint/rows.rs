//! The particle rows read back: a rank's own rows on the writer's rank count, or the
//! rows in its cells, scanned in chunks, on another; each checked against its writer's
//! hash.

use super::access::{attr_u64, attr_vec, dataset, finite, F64_INTEGERS};
use super::{row_hash, Header, CHUNK_ROWS};
use crate::mpm::particles::{Carries, Kinds, Particles};
use crate::physics::shape::Geom;
use crate::physics::tensor::{det, Mat};
use decomposition::Layout;
use std::path::Path;

/// The `particles` dataset of a checkpoint whose records are those `carries` needs.
pub(super) struct Rows<'a> {
    ds: hdf5::Dataset,
    path: &'a Path,
    /// Values per row.
    width: usize,
    /// The arrays its records hold (more than the scene's for a version 3 file).
    pub(super) carries: Carries,
}

impl<'a> Rows<'a> {
    /// Check that the checkpoint's grid and particle records are the scene's (`layout`,
    /// `carries`), and open its particle rows.
    pub(super) fn open<const D: usize>(
        f: &hdf5::File,
        header: &'a Header,
        layout: &Layout<D>,
        carries: Carries,
    ) -> Result<Self, String> {
        let path = &header.path;
        let p = path.display();
        if header.dim != D {
            return Err(format!(
                "{p}: damaged checkpoint: dim {} != {D}",
                header.dim
            ));
        }
        let cells: Vec<u64> = attr_vec(f, path, "cells", D)?;
        if cells
            .iter()
            .zip(&layout.cells)
            .any(|(&a, &b)| a != b as u64)
        {
            return Err(format!(
                "{p}: damaged checkpoint: cells {cells:?} differ from the stored scene's {:?}",
                layout.cells
            ));
        }
        let version = attr_u64(f, path, "version")?;
        let flags = Carries::NAMES
            .iter()
            .map(|&name| match name {
                "stress" if version == 3 => Ok(true),
                "mass" if version <= 4 => Ok(true),
                "vol0" | "vol" if version <= 5 => Ok(true),
                _ => Ok(attr_u64(f, path, &format!("carries_{name}"))? != 0),
            })
            .collect::<Result<Vec<bool>, String>>()?;
        let stored = Carries::from_flags(&flags);
        let width = Particles::<D>::record_width(stored);
        // The stored stress of a version 3 file and the mass of a version 3 or 4 file
        // are read and then dropped, `vol0` before version 6 read into the kind, and
        // the volume before version 6 dropped where the particles carry `F` (`read`).
        let needed = Carries {
            stress: carries.stress || version == 3,
            mass: version <= 4,
            vol0: version <= 5,
            vol: carries.vol || version <= 5,
            ..carries
        };
        if stored != needed || attr_u64(f, path, "record_width")? != width as u64 {
            return Err(format!(
                "{p}: damaged checkpoint: its particle arrays ({stored:?}) are not those the stored scene needs ({carries:?})"
            ));
        }
        let n = header.particles as usize;
        let ds = f
            .dataset("particles")
            .map_err(|e| format!("{p}: damaged checkpoint: dataset `particles`: {e}"))?;
        // HDF5 would convert other numbers on reading (integers, f32) and lose values.
        let f64s = hdf5::types::TypeDescriptor::Float(hdf5::types::FloatSize::U8);
        match ds.dtype().and_then(|t| t.to_descriptor()) {
            Ok(t) if t == f64s => {}
            Ok(t) => {
                return Err(format!(
                "{p}: damaged checkpoint: dataset `particles` holds {t} values, not 64-bit floats"
            ))
            }
            Err(e) => return Err(format!("{p}: damaged checkpoint: dataset `particles`: {e}")),
        }
        if ds.shape() != [n, width] {
            return Err(format!(
                "{p}: damaged checkpoint: dataset `particles` has shape {:?}, expected [{n}, {width}]",
                ds.shape()
            ));
        }
        Ok(Self {
            ds,
            path,
            width,
            carries: stored,
        })
    }

    /// Rows `r0..r1`, back to back.
    fn read(&self, r0: usize, r1: usize) -> Result<Vec<f64>, String> {
        if r0 == r1 {
            return Ok(Vec::new());
        }
        self.ds
            .read_slice_2d::<f64, _>((r0..r1, ..))
            .map(|a| a.iter().copied().collect())
            .map_err(|e| {
                format!(
                    "{}: cannot read particles {r0}..{r1}: {e}",
                    self.path.display()
                )
            })
    }

    /// The rows of writer rank `w` do not match their checksum.
    fn corrupt(&self, w: usize) -> String {
        format!(
            "{}: corrupt checkpoint: the particle rows of writer rank {w} do not match their checksum",
            self.path.display()
        )
    }

    /// The rank of `layout` whose cells hold row `r`, or an error naming the row and
    /// what `check` finds wrong with it.
    fn row<const D: usize>(
        &self,
        check: &RowCheck<D>,
        layout: &Layout<D>,
        r: usize,
        rec: &[f64],
    ) -> Result<usize, String> {
        check.owner(layout, rec).map_err(|what| {
            format!(
                "{}: damaged checkpoint: dataset `particles`, row {r}: {what}",
                self.path.display()
            )
        })
    }

    /// No particle id twice among `parts` (this rank's): ids order particles within a
    /// cell (the bit-for-bit continuation) and name them in the snapshots.
    pub(super) fn unique_ids<const D: usize>(&self, parts: &Particles<D>) -> Result<(), String> {
        let mut ids = parts.id.clone();
        ids.sort_unstable();
        match ids.windows(2).find(|w| w[0] == w[1]) {
            Some(w) => Err(format!(
                "{}: damaged checkpoint: dataset `particles`: particle id {} is in more than one row",
                self.path.display(),
                w[0]
            )),
            None => Ok(()),
        }
    }

    /// Same rank count and process grid as the writer's: this rank's own rows, in the
    /// writer's memory order, and its external work.
    pub(super) fn own<const D: usize>(
        &self,
        writers: &Writers,
        rank: usize,
        layout: &Layout<D>,
        check: &RowCheck<D>,
        carries: Carries,
    ) -> Result<(Particles<D>, f64), String> {
        let mut parts = Particles::<D>::default();
        let r0 = writers.starts[rank];
        let r1 = r0 + writers.rows[rank] as usize;
        let mut hash = 0u64;
        let mut k = 0u64;
        let mut at = r0;
        while at < r1 {
            let end = (at + CHUNK_ROWS).min(r1);
            let buf = self.read(at, end)?;
            for rec in buf.chunks_exact(self.width) {
                hash = hash.wrapping_add(row_hash(k, rec));
                // The writer's rows lie in its block, which is this rank's.
                let r = r0 + k as usize;
                let owner = self.row(check, layout, r, rec)?;
                if owner != rank {
                    return Err(format!(
                        "{}: damaged checkpoint: dataset `particles`, row {r}: a particle of writer rank {rank} lies in the block of rank {owner}",
                        self.path.display()
                    ));
                }
                k += 1;
                parts.unpack(rec, carries);
            }
            at = end;
        }
        if hash != writers.sums[rank] {
            return Err(self.corrupt(rank));
        }
        Ok((parts, writers.work[rank]))
    }

    /// Another rank count, process grid or cuts: the rows of the writers for which
    /// `overlaps` holds (those whose blocks overlap this rank's), keeping those in
    /// this rank's cells, each writer's checksum checked; rank 0 carries the external
    /// work of all writers. Returns the particles, the work and the rows read.
    pub(super) fn all<const D: usize>(
        &self,
        writers: &Writers,
        rank: usize,
        layout: &Layout<D>,
        check: &RowCheck<D>,
        carries: Carries,
        overlaps: impl Fn(usize) -> bool,
    ) -> Result<(Particles<D>, f64, u64), String> {
        let mut parts = Particles::<D>::default();
        let (rows, starts) = (&writers.rows, &writers.starts);
        let mut read = 0u64;
        for w in (0..rows.len()).filter(|&w| overlaps(w)) {
            let (r0, r1) = (starts[w], starts[w] + rows[w] as usize);
            let mut hash = 0u64;
            let mut at = r0;
            while at < r1 {
                let end = (at + CHUNK_ROWS).min(r1);
                let buf = self.read(at, end)?;
                for (i, rec) in buf.chunks_exact(self.width).enumerate() {
                    hash = hash.wrapping_add(row_hash((at + i - r0) as u64, rec));
                    if self.row(check, layout, at + i, rec)? == rank {
                        parts.unpack(rec, carries);
                    }
                }
                at = end;
            }
            if hash != writers.sums[w] {
                return Err(self.corrupt(w));
            }
            read += rows[w];
        }
        let external_work = if rank == 0 {
            writers.work.iter().sum()
        } else {
            0.0
        };
        Ok((parts, external_work, read))
    }
}

/// What a particle row must hold for the solver to step it: finite values, positive
/// mass, volumes and GIMP half-widths, a kind of the scene (before version 6: a
/// material and `vol0` that make one), an integer id,
/// damage in [0, 1], plastic strain >= 0, and a position on the grid (where a step
/// leaves every particle: below the upper face on periodic axes). A row that breaks
/// one made the solver index out of its materials or grid (a panic), or run on with
/// NaN.
pub(super) struct RowCheck<'a, const D: usize> {
    geom: &'a Geom<D>,
    kinds: &'a Kinds,
    /// Per array of the record: column name, first value, values.
    fields: Vec<(&'static str, usize, usize)>,
    /// Where a record before version 6 holds `vol0` (its `kind` column then holds the
    /// material).
    vol0_at: Option<usize>,
    /// The record holds `F` and no volume: the volume is `det F · V₀`.
    volume_of_f: bool,
}

impl<'a, const D: usize> RowCheck<'a, D> {
    pub(super) fn new(geom: &'a Geom<D>, carries: Carries, kinds: &'a Kinds) -> Self {
        let mut at = 0;
        let fields: Vec<_> = Particles::<D>::fields(carries)
            .iter()
            .map(|f| {
                at += f.width;
                (f.column, at - f.width, f.width)
            })
            .collect();
        let vol0_at = fields.iter().find(|f| f.0 == "vol0").map(|f| f.1);
        Self {
            geom,
            kinds,
            fields,
            vol0_at,
            volume_of_f: carries.def_grad && !carries.vol,
        }
    }

    /// What is wrong with `rec`, if anything.
    fn fault(&self, rec: &[f64]) -> Option<String> {
        let g = self.geom;
        for &(name, at, w) in &self.fields {
            let v = &rec[at..at + w];
            if let Some(x) = v.iter().find(|x| !x.is_finite()) {
                return Some(format!("`{name}` holds {x}"));
            }
            let fault = match name {
                "mass" | "vol" | "vol0" | "half" => v
                    .iter()
                    .find(|&&x| x <= 0.0)
                    .map(|x| format!("`{name}` = {x} is not positive")),
                "kind" => self.kind_fault(v[0], rec),
                "def_grad" if self.volume_of_f => {
                    let j = det(&Mat::<D>::from_column_slice(v));
                    (j <= 0.0).then(|| {
                        format!(
                            "`def_grad` has determinant {j}: the volume det F · V₀ is not positive"
                        )
                    })
                }
                "id" => (v[0] < 0.0 || v[0].fract() != 0.0 || v[0] >= F64_INTEGERS as f64)
                    .then(|| format!("particle id {} is not an integer id", v[0])),
                "eps_p" => (v[0] < 0.0).then(|| format!("`eps_p` = {} is negative", v[0])),
                "damage" => (!(0.0..=1.0).contains(&v[0]))
                    .then(|| format!("`damage` = {} is not in [0, 1]", v[0])),
                "x" => (0..D)
                    .find(|&a| {
                        let (lo, hi) = (g.lower[a], g.upper[a]);
                        v[a] < lo || v[a] > hi || (g.periodic[a] && v[a] == hi)
                    })
                    .map(|a| {
                        format!(
                            "position {v:?} is outside the grid on axis {a} ([{}, {}])",
                            g.lower[a], g.upper[a]
                        )
                    }),
                _ => None,
            };
            if fault.is_some() {
                return fault;
            }
        }
        None
    }

    /// What is wrong with a row's `kind` column `k` (`rec` the row): a kind index of
    /// the scene, or before version 6 a material index that makes one with `vol0`.
    fn kind_fault(&self, k: f64, rec: &[f64]) -> Option<String> {
        let n = self.kinds.material.len();
        let index = (k >= 0.0 && k.fract() == 0.0 && k <= f64::from(u16::MAX)).then_some(k as u16);
        match self.vol0_at {
            None => (index.is_none_or(|i| usize::from(i) >= n))
                .then(|| format!("kind index {k} is not one of the scene's {n} kinds of particle")),
            Some(at) => {
                let vol0 = rec[at];
                (index.and_then(|m| self.kinds.find(m, vol0)).is_none()).then(|| {
                    format!(
                        "material index {k} with `vol0` = {vol0} is not a kind of particle of \
                         the stored scene (a body's material with its particles per cell)"
                    )
                })
            }
        }
    }

    /// The rank of `layout` whose cells hold the particle of `rec`, or what is wrong
    /// with it.
    fn owner(&self, layout: &Layout<D>, rec: &[f64]) -> Result<usize, String> {
        if let Some(m) = self.fault(rec) {
            return Err(m);
        }
        let x: [f64; D] = std::array::from_fn(|a| rec[a]);
        let (c, _) = self.geom.locate(&x);
        let cell: [usize; D] =
            std::array::from_fn(|a| c[a].rem_euclid(layout.cells[a] as i64) as usize);
        Ok(layout.cell_owner(cell))
    }
}

/// Per writer rank: its rows, where they start, its external work and its checksum.
pub(super) struct Writers {
    rows: Vec<u64>,
    starts: Vec<usize>,
    work: Vec<f64>,
    sums: Vec<u64>,
}

impl Writers {
    pub(super) fn read(f: &hdf5::File, path: &Path, header: &Header) -> Result<Self, String> {
        let (writers, n) = (header.ranks, header.particles);
        let rows: Vec<u64> = dataset(f, path, "rank_rows", writers)?;
        // Checked: edited counts must not overflow (a panic in a debug build).
        if rows.iter().try_fold(0u64, |s, &r| s.checked_add(r)) != Some(n) {
            return Err(format!(
                "{}: damaged checkpoint: rank_rows {rows:?} do not add up to {n} particles",
                path.display()
            ));
        }
        let work: Vec<f64> = dataset(f, path, "external_work", writers)?;
        finite(path, "dataset `external_work`", &work, false)?;
        let sums: Vec<u64> = dataset(f, path, "checksum", writers)?;
        let starts: Vec<usize> = rows
            .iter()
            .scan(0usize, |acc, &r| {
                let s = *acc;
                *acc += r as usize;
                Some(s)
            })
            .collect();
        Ok(Self {
            rows,
            starts,
            work,
            sums,
        })
    }
}
