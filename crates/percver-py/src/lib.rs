//! `percver._core`: the thin pyo3 layer over the Rust crates. One file per core module,
//! errors mapped in `error.rs`; no algorithm lives here.
use pyo3::prelude::*;

mod closed_loop;
mod error;
mod expr;
mod flowpipe;
mod interval;
mod network;

/// glibc returns a worker thread's freed heap top to the system (madvise) once it exceeds
/// 128 KB, and the next allocation faults the pages in again: the engine's rayon threads free
/// and reallocate Taylor-model and network matrices at every step, and that churn was half
/// the CPU time of long cells, as system time (2.5 million page faults in 9 s of attitude
/// control: bench/README.md). Freed memory up to 64 MB per arena is kept instead; setting
/// the trim threshold turns off glibc's adaptive mmap threshold, so that one is fixed at its
/// adaptive maximum (32 MB) and large matrices stay on the heap.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::raw::c_int;
        extern "C" {
            fn mallopt(param: c_int, value: c_int) -> c_int;
        }
        const M_TRIM_THRESHOLD: c_int = -1;
        const M_MMAP_THRESHOLD: c_int = -3;
        // SAFETY: mallopt only sets allocator parameters; both values are in glibc's range.
        unsafe {
            mallopt(M_TRIM_THRESHOLD, 64 << 20);
            mallopt(M_MMAP_THRESHOLD, 32 << 20);
        }
    }
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    keep_freed_memory();
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
