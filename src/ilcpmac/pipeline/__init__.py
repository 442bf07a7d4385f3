"""The compensation pipeline: stages chained, one joint fit per trial, safety limits."""
