//! Acceleration structures for ray queries. Empty for now: the structures land with the acceleration-structures issue.
