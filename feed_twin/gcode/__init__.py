"""G-code pipeline: lexer -> modal interpreter -> planner -> sampled trajectory."""
