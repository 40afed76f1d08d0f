"""Background jobs: the job table, the handler registry, job status and the server-sent event stream."""
