//! How a cell is verified: Taylor order, network method, splitting budget. The defaults here are
//! the library's one source of them (the Python layer reads them through `percver._core`).
use crate::error::{ReachError, Result};
use nn2hybrid::propagate::Settings as NnSettings;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    Taylor,
    Verisig,
}

#[derive(Clone, Debug)]
pub struct CellSettings {
    pub order: usize,
    pub cutoff: f64,
    pub method: Method,
    pub nn: NnSettings,
    pub timeout: Option<f64>,
    /// Widths beyond which a state enclosure counts as blown up.
    pub blow_up_width: f64,
    /// Branches allowed per cell: domain splits when a part is lost, and forks of parts at an
    /// expression stage's undecided conditions (0: never; conditions then take the hull).
    pub max_splits: usize,
    /// Steps the splits that restart a lost part from an earlier step may compute again, in runs
    /// of the deepest step the cell has reached (None: no bound). A split that would pass it
    /// gives the cell up instead, naming the variable it would have split: a caller that halves
    /// the cell ahead pays a run per piece, while each such split repeats most of a run.
    pub max_redone: Option<f64>,
    /// Restart a part from its box when a remainder is most of a state's enclosure: the
    /// dependency on the initial state is lost, but remainders stop feeding back through the
    /// loop (they can grow geometrically when the controller's correction adds to them).
    pub rebox: bool,
    /// Keep the state's remainders as error symbols from step to step
    /// ([`taylor::error_symbols`]) instead of intervals (Taylor method, discrete plants, no
    /// rebox): their correlations survive the loop, so a controller's correction can cancel an
    /// error instead of adding its magnitude again at every step.
    pub state_symbols: bool,
    /// Raised to the deepest step the cell has reached so far, as it runs: a caller's live
    /// progress display reads it from another thread.
    pub progress: Option<Arc<AtomicUsize>>,
}

impl Default for CellSettings {
    /// Order 5 verifies both case studies' cells (a sixth order pays only in their hardest
    /// bands); 16 splits per cell decide most cells that are decidable at their size.
    fn default() -> CellSettings {
        CellSettings {
            order: 5,
            cutoff: 1e-12,
            method: Method::Taylor,
            nn: NnSettings { order: 5, cutoff: 1e-12, ..NnSettings::default() },
            timeout: None,
            blow_up_width: 1e6,
            max_splits: 16,
            max_redone: None,
            rebox: false,
            state_symbols: false,
            progress: None,
        }
    }
}

impl CellSettings {
    /// The settings with the networks' Taylor order and cutoff following the cell's (a network
    /// order of its own, `nn_order`, when given), checked.
    pub fn with_network_order(mut self, nn_order: Option<usize>) -> Result<CellSettings> {
        self.nn = NnSettings { order: nn_order.unwrap_or(self.order), cutoff: self.cutoff, ..self.nn };
        self.nn.validate()?;
        if !(self.blow_up_width > 0.0) {
            return Err(ReachError::input(format!("blow_up_width must be positive, got {}", self.blow_up_width)));
        }
        if let Some(r) = self.max_redone.filter(|r| !(*r >= 0.0 && r.is_finite())) {
            return Err(ReachError::input(format!(
                "max_redone (runs' steps that splits restarting may compute again) must be a finite non-negative number, got {r}"
            )));
        }
        if self.timeout.is_some_and(|t| !(t > 0.0)) {
            return Err(ReachError::input(format!("the timeout per cell must be positive, got {:?}", self.timeout)));
        }
        Ok(self)
    }
}

impl Method {
    pub fn from_name(name: &str) -> Result<Method> {
        match name {
            "taylor" => Ok(Method::Taylor),
            "verisig" => Ok(Method::Verisig),
            other => Err(ReachError::input(format!("unknown method '{other}'; use 'taylor' or 'verisig'"))),
        }
    }
    pub fn name(&self) -> &'static str {
        match self {
            Method::Taylor => "taylor",
            Method::Verisig => "verisig",
        }
    }
}
