"""The worker process that claims and runs background jobs."""
