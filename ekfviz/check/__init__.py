"""Checking a filter against the reference, event by event, and naming its mistakes."""
