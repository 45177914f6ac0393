"""The review (a person outranks the filter): the HTML review page and PNG contact sheets (`catalog sheet`),
the decisions file the page exports, importing it (`catalog review import`) and applying pair decisions."""
