//! GeoKeyDirectory parsing and writing (in progress).
