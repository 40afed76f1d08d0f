"""Operator edits on the web: previews, edit batches against a base revision, the revision job, revert and diff."""
