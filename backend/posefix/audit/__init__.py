"""The admin's audit view: one person's edits and reviews across runs and tasks (it reads
every domain, so it sits above them rather than inside users)."""
