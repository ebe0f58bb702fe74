"""ltlnav service: the command line now; the REST API, database and dashboard later."""
