//! `percver._core`: the thin pyo3 layer over the Rust crates. One file per core module,
//! errors mapped in `error.rs`; no algorithm lives here.
use pyo3::prelude::*;

/// The engine allocates and frees small Taylor-model vectors by the million per cell, from
/// rayon's threads: glibc's malloc spent 15-20% of an F1/10 cell in allocation and freeing, and
/// trimmed worker-thread heaps so that large network matrices faulted their pages in again at
/// every step (2.5 million page faults in 9 s of attitude control). mimalloc keeps per-thread
/// free lists and keeps freed pages mapped (bench/README.md, F1/10 cost per cell).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod closed_loop;
mod error;
mod expr;
mod flowpipe;
mod interval;
mod network;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<interval::PyInterval>()?;
    m.add_class::<expr::PyExpr>()?;
    m.add_class::<expr::PyCondition>()?;
    m.add_class::<expr::PyTaylorModels>()?;
    m.add_class::<flowpipe::PyFlowpipe>()?;
    m.add_function(wrap_pyfunction!(expr::eval_float, m)?)?;
    m.add_function(wrap_pyfunction!(expr::eval_interval, m)?)?;
    m.add_function(wrap_pyfunction!(expr::taylor_models, m)?)?;
    m.add_function(wrap_pyfunction!(expr::parse_condition, m)?)?;
    m.add_function(wrap_pyfunction!(flowpipe::flowpipe, m)?)?;
    m.add_class::<flowpipe::PyHybridRun>()?;
    m.add_function(wrap_pyfunction!(flowpipe::hybrid_reach, m)?)?;
    m.add_class::<network::PyNetwork>()?;
    m.add_class::<network::PyNetworkModels>()?;
    m.add_class::<closed_loop::PyClosedLoop>()?;
    m.add_class::<closed_loop::PyCellSettings>()?;
    m.add_class::<closed_loop::PyStepCounter>()?;
    m.add_class::<closed_loop::PyCellOutcome>()?;
    m.add_function(wrap_pyfunction!(closed_loop::verify_cells, m)?)?;
    m.add_function(wrap_pyfunction!(closed_loop::_cell_settings, m)?)?;
    Ok(())
}
