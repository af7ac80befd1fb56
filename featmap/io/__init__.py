"""Readers and writers. Every writer is atomic (temp file + rename) and most have a reader twin."""
