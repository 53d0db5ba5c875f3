"""One router per concern: jobs, library, health, pages."""
