"""Seed 004: direct position estimation (DPE) and its vertical protection level (DPE.md)."""
