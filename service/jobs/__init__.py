"""The Celery app and tasks, in service because they read and write the service's database."""
