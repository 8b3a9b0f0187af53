//! The source papers' experiments, reproducible from the command line.
