"""The API's routes, one router per concern; `app.create_app` includes them in this order (the OpenAPI order)."""
