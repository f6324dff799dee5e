//! Prints the memory cost of the core's types at the reference configuration (bytes).
fn main() {
    println!(
        "ReferenceTables: {} bytes (flash, one static)",
        std::mem::size_of::<stjpdacf::tables::ReferenceTables>()
    );
}
