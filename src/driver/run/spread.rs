//! A per-rank figure as `summary.json` reports it: its least, mean and largest value
//! over the ranks.

use decomposition::Communicator;
use serde::Serialize;

/// `min`, `mean` and `max` over ranks of a per-rank figure that need not be whole.
#[derive(Serialize, Debug, Clone)]
pub struct Spread {
    pub min: f64,
    pub mean: f64,
    pub max: f64,
}

impl Spread {
    /// Collective: the spread over ranks of each of this rank's figures `mine`; three
    /// reductions.
    pub fn over_ranks(comm: &dyn Communicator, mine: &[f64]) -> Vec<Spread> {
        let (mut lo, mut hi, mut sum) = (mine.to_vec(), mine.to_vec(), mine.to_vec());
        comm.min_f64(&mut lo);
        comm.max_f64(&mut hi);
        comm.sum_f64(&mut sum);
        let n = comm.size() as f64;
        (0..mine.len())
            .map(|k| Spread {
                min: lo[k],
                mean: sum[k] / n,
                max: hi[k],
            })
            .collect()
    }
}
