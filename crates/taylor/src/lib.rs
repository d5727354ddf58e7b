//! `taylor`: validated numerics for reachability.
//!
//! Layers, each in its own module and usable alone:
//! intervals ([`interval`]) -> monomial layout ([`space`]) -> Taylor models ([`tm`]) ->
//! elementary functions ([`functions`]) and range bounding ([`bound`]) -> expressions
//! ([`expr`], [`parser`]) -> ODE flowpipes ([`flowpipe`], [`precondition`]; wide ODEs group by
//! group, [`coupling`]) -> hybrid automata ([`hybrid`]);
//! discrete-time error symbols ([`error_symbols`], [`parallelotope`]).
pub mod bound;
pub mod coupling;
pub mod error;
pub mod error_symbols;
pub mod expr;
pub mod flowpipe;
pub mod functions;
pub mod hybrid;
pub mod interval;
pub mod parallelotope;
pub mod parser;
pub mod precondition;
pub mod space;
pub mod symbolic;
pub mod tm;

pub use error::{Result, TaylorError};
pub use expr::{Algebra, BinOp, Cmp, Expr, Program};
pub use flowpipe::{reach, Flowpipe, Ode, OrderPolicy, Segment, Settings, StepSize};
pub use functions::Func;
pub use interval::Interval;
pub use precondition::Precondition;
pub use space::Space;
pub use tm::{Ctx, TaylorModel};
