"""Crowd tasks (HITs): the queue and leases, submissions, consensus, review, merge, qualification and gold runs."""
