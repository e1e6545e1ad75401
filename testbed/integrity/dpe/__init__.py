"""Direct position estimation (DPE) and its vertical protection level (the DPE paper; docs/design/dpe.md)."""
