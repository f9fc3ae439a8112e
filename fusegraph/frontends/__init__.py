"""Signal processing that makes measurements from raw streams."""
