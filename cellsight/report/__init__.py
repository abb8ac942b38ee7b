"""Pictures and reports: the cell overview, run figures and the HTML report."""
