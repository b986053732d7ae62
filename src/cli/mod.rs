#[cfg(feature = "lab")]
pub mod bench;
pub mod ctl;
#[cfg(feature = "lab")]
pub mod demo;
#[cfg(feature = "lab")]
pub mod plan;
pub mod run;
