"""The paper's scenarios as functions returning results (numbers and arrays, no figures)."""
