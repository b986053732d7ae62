pub mod bench;
pub mod demo;
pub mod plan;
pub mod run;
