"""Run-level analysis above the export floor: the consistency test of the inputs (and the skip decision
of the view-adaptive phases), the diagnostics pictures of view-adaptive runs."""
