from supportnet.cli.app import main

main()
