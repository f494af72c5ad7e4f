//! Evaluation: what the methods cost and how accurate they are, measured through the driver.
//! `bench` (the cost model's terms and eq. 16), `reference` (cached high-sample frames),
//! `errors` (error, flicker and their fits), `compare` (every method against the reference) and
//! `chart` (SVG and PNG charts).
pub mod bench;
pub mod chart;
pub mod compare;
pub mod errors;
pub mod reference;

/// The first element of `list` that an earlier one equals (a value given twice in a list flag:
/// its runs were made twice, and one's results lost).
pub(crate) fn first_repeat<T: PartialEq>(list: &[T]) -> Option<&T> {
    (list.iter().enumerate()).find_map(|(i, x)| list[..i].contains(x).then_some(x))
}
