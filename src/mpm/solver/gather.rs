//! Grid to particle: the gather, MUSL's remap and the stress update.

use super::*;

impl<'c, const D: usize> Solver<'c, D> {
    /// MUSL's remap ([`Phase::Remap`]): new particle velocities, and their momentum
    /// summed over ranks into the scatter records' momentum (the rest of the records,
    /// mass and cover among them, is the step's scatter's).
    pub(super) fn remap(&mut self, dt: f64, kick: f64) -> bool {
        // Summed into the records' momentum slots in place: no field of its own.
        let (sw, mom) = (self.grid.sw, NodeRecord::<D>::momentum(0));
        self.grid
            .scat
            .par_chunks_mut(sw * ZERO_CHUNK)
            .for_each(|recs| {
                for rec in recs.chunks_exact_mut(sw) {
                    rec[mom..mom + D].fill(0.0);
                }
            });
        let mut ctx = ctx!(self);
        ctx.walls = self.has_walls();
        let parts = crate::mpm::remap::RemapParts {
            x: &self.parts.x,
            mass: particles::Masses::of(&self.kinds, &self.parts.kind),
            x0: &self.parts.x0,
            half: &self.parts.half,
            def_grad: &self.parts.def_grad,
            tile: &self.place.ptile,
            accel: &self.scratch.accel,
        };
        let m = crate::mpm::remap::RemapMode {
            dt,
            kick,
            flip: self.flip,
            record: (sw, mom),
        };
        let t = match (self.scheme.wide(), D) {
            (false, 1) => remap::<D, 2, 2>,
            (false, 2) => remap::<D, 2, 4>,
            (false, _) => remap::<D, 2, 8>,
            (true, 1) => remap::<D, 3, 3>,
            (true, 2) => remap::<D, 3, 9>,
            (true, _) => remap::<D, 3, 27>,
        }(
            &ctx,
            &parts,
            &mut self.parts.v,
            &self.place.slabs,
            &self.grid.vel,
            &mut self.grid.scat,
            m,
        );
        self.block
            .ghost_sum_slots(self.comm, &mut self.grid.scat, sw, mom..mom + D);
        self.external_work += t.work;
        t.ok
    }

    /// Whether a grid face is a wall (slip or fixed): the passes that clip or blend
    /// velocities there need each particle's wall ends.
    pub(super) fn has_walls(&self) -> bool {
        self.faces
            .iter()
            .flatten()
            .any(|f| matches!(f, Face::Slip | Face::Fixed))
    }

    /// Grid → particle: velocities (FLIP/PIC blend) and positions from slot 1, and if
    /// `stress` the velocity gradient, deformation and stress; positions if `move_now`
    /// (under MUSL the stress pass moves the particles).
    /// `speed`: this is the step's last particle pass, which sets the signal speed the
    /// next step size follows.
    pub(super) fn gather(
        &mut self,
        (dt, kick): (f64, f64),
        stress: bool,
        move_now: bool,
        speed: bool,
    ) -> bool {
        let mode = kernel::GatherMode {
            dt,
            kick,
            flip: self.flip,
            stress,
            move_now,
            two_step: self.scheme.two_step(),
            recon: self.scheme.two_step() && move_now,
            speed,
        };
        let mut ctx = ctx!(self);
        ctx.walls = self.has_walls();
        let parts = slices!(self);
        let t = by_nodes!(
            self.scheme.wide(),
            gather,
            &ctx,
            parts,
            &self.grid.vel,
            avg_of::<D>(&self.grid.scat, self.grid.node_vol.len()),
            self.xpic.map(|_| &self.grid.xpic_add[..]),
            mode
        );
        self.external_work += t.work;
        if speed {
            self.max_speed = t.max_speed;
            self.speed_agreed = false;
        }
        t.ok
    }

    /// Stress update from grid velocity slot `slot` at the current positions.
    pub(super) fn update_stress_from(
        &mut self,
        slot: usize,
        dt: f64,
        speed: bool,
        moves: bool,
    ) -> bool {
        let m = kernel::StressMode {
            slot,
            dt,
            two_step: self.scheme.two_step(),
            moves,
            speed,
        };
        let mut ctx = ctx!(self);
        ctx.walls = m.moves && self.has_walls();
        let parts = slices!(self);
        let t = by_nodes!(
            self.scheme.wide(),
            update_stress,
            &ctx,
            parts,
            &self.grid.vel,
            avg_of::<D>(&self.grid.scat, self.grid.node_vol.len()),
            m
        );
        self.external_work += t.work;
        if speed {
            self.max_speed = t.max_speed;
            self.speed_agreed = false;
        }
        t.ok
    }
}
