"""Sessions: the append-only capture format, its writer and reader, history of a unit."""
