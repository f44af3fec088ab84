pub fn _x() {}

pub mod fpfdcnn;
pub mod nn;
pub mod sdfcnn;
