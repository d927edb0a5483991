"""Reproductions of the documents' studies; each returns labelled results and can write plots."""
