"""What the applications (svr, mvr) share, below both: never imports svr or mvr."""
