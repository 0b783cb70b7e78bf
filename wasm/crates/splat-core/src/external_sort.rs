//! The external (Web Worker) depth-sort protocol of the instanced path: the renderer files a `SortRequest`
//! (data version + one depth row per view), at most one is in flight, and answers that are not the request in
//! flight or whose indices no longer name the same Gaussians are dropped (web/docs/viewer.md).

use crate::cpu_sort::SortKey;
use crate::poses::PosedRange;

/// Where the instanced path's depth order comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CpuSortSource {
    /// Sorted inside `render` (one shot, or sliced by `cpu_sort_budget_ms`).
    InThread,
    /// Sorted elsewhere (a browser Web Worker): `render` draws the last order it was given and asks for a new one
    /// through `take_sort_request`; `accept_sort_result` hands the order in.
    External,
}

/// A depth sort for an external sorter: the positions of `records_version` (`positions()`), one depth row per view
/// and, per view, the agent objects' posed depth rows (their records sort by those; a new pose changes the rows,
/// not the positions).
#[derive(Clone, Debug, PartialEq)]
pub struct SortRequest {
    pub seq: u64,
    pub keys: Vec<SortKey>,
    pub records_version: u64,
    pub posed: Vec<Vec<PosedRange>>,
}

impl SortRequest {
    pub fn data_version(&self) -> u64 {
        self.keys.first().map_or(0, |k| k.data_version)
    }
}

/// State of the external sort: the orders in hand (one per view slot), what the last render wanted, the one
/// request in flight (a new one goes out only when the previous answered, so a busy sorter never queues stale work).
#[derive(Default)]
pub(crate) struct ExternalSort {
    pub(crate) orders: Vec<(SortKey, Vec<u32>)>,
    pub(crate) wanted: Option<Vec<SortKey>>,
    in_flight: Option<(u64, Vec<SortKey>)>,
    seq: u64,
    pub(crate) dropped: u64,
}

impl ExternalSort {
    /// Forget orders, wishes and the request in flight; sequence numbers and the drop count go on.
    pub(crate) fn reset(&mut self) {
        *self = ExternalSort { seq: self.seq, dropped: self.dropped, ..Default::default() };
    }

    /// The orders in hand are exactly those of `keys`.
    pub(crate) fn orders_ready(&self, keys: &[SortKey]) -> bool {
        keys.len() <= self.orders.len() && keys.iter().zip(&self.orders).all(|(k, o)| *k == o.0)
    }

    /// Ask for the orders of `keys` unless they are in hand.
    pub(crate) fn want(&mut self, keys: Vec<SortKey>) {
        if !self.orders_ready(&keys) {
            self.wanted = Some(keys);
        }
    }

    /// The request to send now (nothing while one is in flight, or when what was wanted is for other data).
    pub(crate) fn take_request(&mut self, data_version: u64) -> Option<SortRequest> {
        if self.in_flight.is_some() {
            return None;
        }
        let keys = self.wanted.take()?;
        if keys.first().is_none_or(|k| k.data_version != data_version) {
            return None; // wanted for data that is gone (a new scene); the next render asks again
        }
        self.seq += 1;
        self.in_flight = Some((self.seq, keys.clone()));
        Some(SortRequest { seq: self.seq, keys, records_version: 0, posed: Vec::new() })
        // the renderer fills the rest
    }

    /// An answer to request `seq`: applied (true), dropped (false: not the request in flight, or its indices
    /// predate `index_epoch`), or an error (wrong number of orders, an index not below `count`).
    pub(crate) fn accept(&mut self, seq: u64, orders: Vec<Vec<u32>>, index_epoch: u64, count: u32) -> Result<bool, String> {
        let keys = match &self.in_flight {
            Some((s, _)) if *s == seq => self.in_flight.take().unwrap().1,
            _ => {
                self.dropped += 1;
                return Ok(false);
            }
        };
        if keys.first().is_none_or(|k| k.data_version < index_epoch) {
            self.dropped += 1; // its indices no longer name the same Gaussians
            return Ok(false);
        }
        if orders.len() != keys.len() {
            return Err(format!("sort result {seq}: {} orders for {} views", orders.len(), keys.len()));
        }
        if let Some(bad) = orders.iter().flatten().find(|&&i| i >= count) {
            return Err(format!("sort result {seq}: index {bad} is out of range (count {count})"));
        }
        if self.wanted.as_ref() == Some(&keys) {
            self.wanted = None;
        }
        self.orders = keys.into_iter().zip(orders).collect();
        Ok(true)
    }

    /// The sorter died: the request in flight is wanted again.
    pub(crate) fn cancel(&mut self) {
        if let Some((_, keys)) = self.in_flight.take() {
            self.wanted.get_or_insert(keys);
        }
    }
}
