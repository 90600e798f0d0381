"""Readers of the files people record: tables (CSV, text, npy, npz), row files streamed from disk, the real recordings."""
