//! A rank's local block: its node box with ghost layers and the halo operations on
//! nodal fields stored node-major (`field[node * ncomp + c]`).

use crate::comm::Communicator;
use crate::layout::{Layout, GHOST};

/// One rank's view of the grid.
#[derive(Clone, Debug)]
pub struct Block<const D: usize> {
    pub rank: usize,
    /// Owned cells `[cell_lo, cell_hi)`, global indices.
    pub cell_lo: [usize; D],
    pub cell_hi: [usize; D],
    /// Global (unwrapped) index of local node 0 along each axis; negative on a periodic
    /// axis whose ghost layer wraps below 0.
    pub node_lo: [i64; D],
    /// Local node box size along each axis.
    pub node_dims: [usize; D],
    /// Owned nodes in local indices, `[own_lo, own_hi)` along each axis.
    pub own_lo: [usize; D],
    pub own_hi: [usize; D],
    halo: Halo,
}

/// For each peer rank: which of my ghost nodes it owns, and which of my owned nodes are
/// ghosts in its box, both in the order of the peer's (resp. my) local node numbering so
/// that the two sides agree without talking.
#[derive(Clone, Debug, Default)]
struct Halo {
    peers: Vec<usize>,
    /// `ghosts[k]`: my local ghost nodes owned by `peers[k]`.
    ghosts: Vec<Vec<usize>>,
    /// `owned[k]`: my local owned nodes that are ghosts of `peers[k]`, in the order of
    /// that peer's `ghosts` list for me.
    owned: Vec<Vec<usize>>,
    send: Vec<Vec<f64>>,
    recv: Vec<Vec<f64>>,
}

impl<const D: usize> Block<D> {
    pub fn new(layout: &Layout<D>, rank: usize) -> Self {
        let (cell_lo, cell_hi) = layout.block_cells(rank);
        let (node_lo, node_dims, own_lo, own_hi) = node_box(layout, rank);
        let mut b = Self {
            rank,
            cell_lo,
            cell_hi,
            node_lo,
            node_dims,
            own_lo,
            own_hi,
            halo: Halo::default(),
        };
        b.halo = build_halo(layout, rank);
        b
    }

    pub fn num_nodes(&self) -> usize {
        self.node_dims.iter().product()
    }

    /// Local linear index of a local node coordinate (axis 0 fastest).
    #[inline]
    pub fn index(&self, local: [usize; D]) -> usize {
        let mut i = 0;
        for a in (0..D).rev() {
            i = i * self.node_dims[a] + local[a];
        }
        i
    }

    /// Local node coordinate of a linear index.
    #[inline]
    pub fn coords(&self, mut i: usize) -> [usize; D] {
        let mut c = [0; D];
        for a in 0..D {
            c[a] = i % self.node_dims[a];
            i /= self.node_dims[a];
        }
        c
    }

    /// Global (unwrapped) node index of a local coordinate.
    #[inline]
    pub fn global(&self, local: [usize; D]) -> [i64; D] {
        let mut g = [0; D];
        for a in 0..D {
            g[a] = self.node_lo[a] + local[a] as i64;
        }
        g
    }

    pub fn is_owned(&self, local: [usize; D]) -> bool {
        (0..D).all(|a| local[a] >= self.own_lo[a] && local[a] < self.own_hi[a])
    }

    /// Peers this rank exchanges halo data with (itself included on periodic faces).
    pub fn peers(&self) -> &[usize] {
        &self.halo.peers
    }

    /// Add every ghost node's value into its owner's node, then leave ghosts as they were
    /// (call [`Block::ghost_copy`] if they must hold the sum too).
    pub fn ghost_sum(&mut self, comm: &dyn Communicator, field: &mut [f64], ncomp: usize) {
        let h = &mut self.halo;
        for (k, nodes) in h.ghosts.iter().enumerate() {
            let buf = &mut h.send[k];
            buf.clear();
            for &n in nodes {
                buf.extend_from_slice(&field[n * ncomp..(n + 1) * ncomp]);
            }
        }
        comm.exchange(&h.peers, &h.send, &mut h.recv);
        for (k, nodes) in h.owned.iter().enumerate() {
            let buf = &h.recv[k];
            debug_assert_eq!(buf.len(), nodes.len() * ncomp);
            for (j, &n) in nodes.iter().enumerate() {
                for c in 0..ncomp {
                    field[n * ncomp + c] += buf[j * ncomp + c];
                }
            }
        }
    }

    /// Copy every owned node's value to all its ghost copies on all ranks.
    pub fn ghost_copy(&mut self, comm: &dyn Communicator, field: &mut [f64], ncomp: usize) {
        let h = &mut self.halo;
        for (k, nodes) in h.owned.iter().enumerate() {
            let buf = &mut h.send[k];
            buf.clear();
            for &n in nodes {
                buf.extend_from_slice(&field[n * ncomp..(n + 1) * ncomp]);
            }
        }
        comm.exchange(&h.peers, &h.send, &mut h.recv);
        for (k, nodes) in h.ghosts.iter().enumerate() {
            let buf = &h.recv[k];
            debug_assert_eq!(buf.len(), nodes.len() * ncomp);
            for (j, &n) in nodes.iter().enumerate() {
                field[n * ncomp..(n + 1) * ncomp].copy_from_slice(&buf[j * ncomp..(j + 1) * ncomp]);
            }
        }
    }
}

type NodeBox<const D: usize> = ([i64; D], [usize; D], [usize; D], [usize; D]);

fn node_box<const D: usize>(layout: &Layout<D>, rank: usize) -> NodeBox<D> {
    let (lo, hi) = layout.block_cells(rank);
    let mut node_lo = [0i64; D];
    let mut dims = [0usize; D];
    let mut own_lo = [0usize; D];
    let mut own_hi = [0usize; D];
    for a in 0..D {
        let n = layout.cells[a];
        let per = layout.periodic[a];
        let below = if per || lo[a] > 0 { GHOST } else { 0 };
        let above = if per || hi[a] < n { GHOST } else { 0 };
        node_lo[a] = lo[a] as i64 - below as i64;
        // Nodes lo-below ..= hi+above.
        dims[a] = hi[a] - lo[a] + below + above + 1;
        own_lo[a] = below;
        own_hi[a] = below + hi[a] - lo[a] + usize::from(!per && hi[a] == n);
    }
    (node_lo, dims, own_lo, own_hi)
}

/// Ghost nodes of `rank`'s box, as (local index, wrapped global node), in local order.
fn ghost_nodes<const D: usize>(layout: &Layout<D>, rank: usize) -> Vec<(usize, [usize; D])> {
    let (node_lo, dims, own_lo, own_hi) = node_box(layout, rank);
    let total: usize = dims.iter().product();
    let mut out = Vec::new();
    for i in 0..total {
        let mut c = [0usize; D];
        let mut r = i;
        for a in 0..D {
            c[a] = r % dims[a];
            r /= dims[a];
        }
        if (0..D).all(|a| c[a] >= own_lo[a] && c[a] < own_hi[a]) {
            continue;
        }
        let mut g = [0i64; D];
        for a in 0..D {
            g[a] = node_lo[a] + c[a] as i64;
        }
        let w = layout
            .wrap_node(g)
            .expect("a node box lies inside the grid on bounded axes");
        out.push((i, w));
    }
    out
}

fn build_halo<const D: usize>(layout: &Layout<D>, rank: usize) -> Halo {
    let nranks = layout.ranks();
    let (my_lo, dims, own_lo, _) = node_box(layout, rank);
    // Local index on this rank of a wrapped global node it owns.
    let local_of_owned = |w: [usize; D]| -> usize {
        let mut i = 0;
        for a in (0..D).rev() {
            let l = (w[a] as i64 - my_lo[a]) as usize;
            debug_assert!(l >= own_lo[a]);
            i = i * dims[a] + l;
        }
        i
    };
    let mut ghosts_by: Vec<Vec<usize>> = vec![Vec::new(); nranks];
    for (i, w) in ghost_nodes(layout, rank) {
        ghosts_by[layout.node_owner(w)].push(i);
    }
    let mut owned_by: Vec<Vec<usize>> = vec![Vec::new(); nranks];
    // Only blocks within one block-step in every direction can hold my nodes as ghosts;
    // scanning all ranks is simpler and only runs at set-up.
    for (other, list) in owned_by.iter_mut().enumerate() {
        for (_, w) in ghost_nodes(layout, other) {
            if layout.node_owner(w) == rank {
                list.push(local_of_owned(w));
            }
        }
    }
    let mut h = Halo::default();
    for p in 0..nranks {
        if !ghosts_by[p].is_empty() || !owned_by[p].is_empty() {
            h.peers.push(p);
            h.ghosts.push(std::mem::take(&mut ghosts_by[p]));
            h.owned.push(std::mem::take(&mut owned_by[p]));
        }
    }
    h.send = vec![Vec::new(); h.peers.len()];
    h.recv = vec![Vec::new(); h.peers.len()];
    h
}
