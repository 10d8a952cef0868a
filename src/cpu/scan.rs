//! CPU twin of `kernels/scan.wgsl`: an exclusive prefix sum of u32 values in place, by runs
//! of 64 like the GPU (integers, so the result is exact and identical).

/// Values per block (one run of `scan_local`, one GPU thread).
pub const SCAN_BLOCK: usize = 64;

/// `scan_local` threads for `n` values (one per run).
pub fn n_runs(n: u32) -> u32 {
    n.div_ceil(SCAN_BLOCK as u32)
}

/// Number of blocks for `n` values (the totals array holds one more: the grand total).
pub fn n_blocks(n: usize) -> usize {
    n.div_ceil(SCAN_BLOCK)
}

/// Per block: exclusive scan of the block in place; its total into `scan_blocks[block]`.
pub fn scan_local(n: usize, scan_data: &mut [u32], scan_blocks: &mut [u32]) {
    for (b, total) in scan_blocks.iter_mut().take(n_blocks(n)).enumerate() {
        let mut sum = 0u32;
        for v in &mut scan_data[b * SCAN_BLOCK..((b + 1) * SCAN_BLOCK).min(n)] {
            let x = *v;
            *v = sum;
            sum = sum.wrapping_add(x);
        }
        *total = sum;
    }
}

/// Exclusive scan of the block totals; the grand total into `scan_blocks[n_blocks]`.
pub fn scan_totals(n: usize, scan_blocks: &mut [u32]) {
    let nb = n_blocks(n);
    let mut sum = 0u32;
    for v in &mut scan_blocks[..nb] {
        let x = *v;
        *v = sum;
        sum = sum.wrapping_add(x);
    }
    scan_blocks[nb] = sum;
}

/// Add each block's offset to its values.
pub fn scan_apply(n: usize, scan_data: &mut [u32], scan_blocks: &[u32]) {
    for (i, v) in scan_data[..n].iter_mut().enumerate() {
        *v = v.wrapping_add(scan_blocks[i / SCAN_BLOCK]);
    }
}

/// The three passes: exclusive prefix sum of `data[..n]`; returns the total.
pub fn exclusive_scan(n: usize, data: &mut [u32]) -> u32 {
    let mut blocks = vec![0u32; n_blocks(n) + 1];
    scan_local(n, data, &mut blocks);
    scan_totals(n, &mut blocks);
    scan_apply(n, data, &blocks);
    blocks[n_blocks(n)]
}
