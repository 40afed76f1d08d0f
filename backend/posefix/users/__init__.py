"""Accounts: users, login sessions, API tokens, throttling and the admin's audit view."""
